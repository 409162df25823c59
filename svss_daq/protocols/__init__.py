"""Wire protocols this project defines: the transmit sequencer (serial, ASCII sentences)
and the digitiser (TCP, binary frames). Pure codecs; no I/O. See ``docs/protocols.md``."""
