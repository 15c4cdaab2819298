"""Closer/farther (motion) sensors (paper 002): the velocity estimators and their base-station
trackers."""
