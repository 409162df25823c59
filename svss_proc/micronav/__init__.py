"""Micronavigation: the array's ping-to-ping motion from the echoes themselves
(docs/micronavigation.md)."""
