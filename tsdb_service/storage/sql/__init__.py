"""SQL shared by the DuckDB and PostgreSQL backends: the dialect, the readers by role, the write statements."""
