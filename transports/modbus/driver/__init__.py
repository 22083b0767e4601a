"""The Modbus media: the serial/pty link, the RTU line and its poll task, the TCP line."""
