"""The Modbus transports (the core's contract): RTU and TCP."""
