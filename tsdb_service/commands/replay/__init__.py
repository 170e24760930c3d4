"""``tsdb-service replay``: stored history sent again to a broker, an MQTT topic or another tsdb-service.

``source`` reads the history as updates in time order, ``targets`` renders
and sends them as each receiver documents, ``runner`` paces them.
"""
