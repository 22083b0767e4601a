"""The Modbus simulators: RTU on a serial line or pty, TCP on a socket."""
