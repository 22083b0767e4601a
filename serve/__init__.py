"""``starterbus serve``: the fleet as a Sparkplug B edge node on an MQTT broker, with Prometheus metrics.

``session`` is the sans-IO edge node (samples, connection events, commands and times in; messages out),
``driver`` runs it on asyncio with paho-mqtt, ``schema`` is the Sparkplug B payload schema written from the
specification, ``prometheus`` exports the fleet for scraping.
"""
