"""The one-command demo: the use cases' simulators (``usecases``) replayed
against a service as Orion would, and the request collection.

Modules: ``runner`` (pacing, HTTP, progress); ``serve`` (the demo's own
service process); ``collection`` (the request collection and its exports).
The CLI is ``cli.demo``; the subscriptions that make a real broker feed us
are ``broker.subscriptions``.
"""
