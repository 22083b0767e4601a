"""OPC UA server for a starterbus fleet (asyncua): one object per device, methods and writes on the guarded path.

``starterbus.opcua.server.OpcUaServer`` runs inside an existing asyncio loop beside an
:class:`~starterbus.aio.AsyncFleet`; ``starterbus opcua FLEET.toml`` starts both. See ``docs/opcua.md``.
"""
