"""SVSS acquisition: configuration, array geometry, pings and their messages, files,
wire protocols and device drivers."""

__version__ = "0.1.0"
