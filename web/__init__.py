"""The fleet in a browser: pages and a JSON API served by aiohttp on the event loop of ``serve`` (docs/web.md).

``starterbus.web.server.WebServer`` runs beside an :class:`~starterbus.aio.AsyncFleet` and reads nothing but
what the fleet hands to asyncio (samples, line statistics, jobs on the bus workers): the I/O beneath can change
without touching the pages.
"""
