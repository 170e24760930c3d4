"""HTTP routes, one module per NGSI concept."""
