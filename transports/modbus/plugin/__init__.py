"""The modbus-rtu and modbus-tcp transport plugins."""
