"""``tsdb-service``: every command, the top of the house (``main`` runs them)."""
