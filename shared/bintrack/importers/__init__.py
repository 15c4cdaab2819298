"""Readers that turn recordings in other formats into DESIGN §6 datasets (``bintrack import``)."""
