"""Where notifications come in: ``POST /v2/notify`` and ``/ngsi-ld/v1/notify``
(``http_notify``), parsed by ``parse`` and written through the write seam."""
