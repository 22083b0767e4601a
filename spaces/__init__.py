"""Address spaces any transport plugin may speak (public API): a model describes each once, and every
transport declaring the space (``TransportPlugin.address_space``) serves every model that has it.

- :mod:`starterbus.spaces.modbus`: Modbus holding registers (``modbus``), spoken by ``modbus-rtu`` and
  ``modbus-tcp``.
"""
