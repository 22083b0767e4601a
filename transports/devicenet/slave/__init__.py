"""A DeviceNet slave node as a sans-IO machine: what the simulator answers on the bus."""
