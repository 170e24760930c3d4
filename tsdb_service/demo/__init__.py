"""The one-command demo: use-case simulators that notify like Orion, the
subscriptions that would make a real broker do it, and the request collection.

Modules: ``lawnmower``, ``warehouse``, ``drone`` (pure, seeded physics);
``orion`` (notification bodies and headers); ``runner`` (pacing, HTTP,
progress); ``serve`` (the demo's own service process); ``subscriptions``
(Orion payloads and recorded examples); ``collection`` (the request
collection and its exports); ``enums`` and ``sites`` (shared constants);
``commands`` (the CLI).
"""
