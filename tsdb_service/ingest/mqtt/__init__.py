"""Notifications over MQTT (issue 31; docs/mqtt.md): Orion, Orion-LD and any
MQTT publisher's notifications from a broker, stored through the same write
seam as ``POST /v2/notify`` and acknowledged once durable.

``config`` (the settings, checked), ``topics`` (which tenant and service path
a topic names), ``messages`` (a message into samples or a rejection) and
``consumer`` (the paho-mqtt client, delivery bookkeeping, acknowledgements).
Importing this package imports no MQTT client: ``consumer`` does.
"""
