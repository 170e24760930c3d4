"""Helpers shared by the test suite (server subprocesses, ...)."""
