"""The modbus-rtu transport plugin."""
