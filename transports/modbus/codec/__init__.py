"""The Modbus wire format: CRC, PDUs and ADUs, character timing, the receiver of an RTU answer (no I/O)."""
