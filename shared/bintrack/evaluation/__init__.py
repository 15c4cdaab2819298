"""Scoring results against truth: the metrics of the papers, the report of ``bintrack eval`` and
its plots."""
