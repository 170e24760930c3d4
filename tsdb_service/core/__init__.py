"""The vocabulary every layer speaks: the ingest model (``model``), what a
read asks for and returns (``query``), the one error hierarchy (``errors``),
settings (``config``), read budgets, time formats, RE2 patterns, retention
policies, credential redaction. Imports nothing else of the service."""
