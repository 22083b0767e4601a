"""Where PKW meets the medium: the cycle driver of a station, its channels (in-process slave, Modbus TCP
gateway) and the lock that keeps one master per station."""
