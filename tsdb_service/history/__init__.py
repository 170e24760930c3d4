"""History queries: parse (``params``), answer (``service``), render (``shape``).

The read API is QuantumLeap 1.0's; ``query`` holds the frozen request
values that storage renders to SQL (``storage.sql``).
"""
