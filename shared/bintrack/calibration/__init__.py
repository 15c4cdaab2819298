"""Sensor models learned from a recording (``bintrack calibrate``): each disk sensor's footprint
radius, pd, pfa and hold time, from the detections alone or, for comparison, from the truth."""
