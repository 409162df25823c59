"""Hostile inputs (issue 13): damaged, truncated and mutated files, full disks, stale
outputs. Shared helpers in conftest.py."""
