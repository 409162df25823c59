"""The seabed from the echoes: the sediment's sound speed and layers (docs/seabed.md)."""
