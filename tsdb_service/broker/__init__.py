"""What we ask of a context broker: the Orion subscriptions that make it
notify us (``subscriptions``), for the CLI, the demo and ``/v2/subscribe``."""
