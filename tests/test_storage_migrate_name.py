"""``tsdb_service.storage.migrate`` stays the function behind ``tsdb-service
migrate`` after the backends loaded the migration files. Their module was
once named ``storage.migrate`` too, and the first import of a submodule
rebinds its name on the package: the command would have called a module."""

from __future__ import annotations

import subprocess
import sys


def test_migrate_is_the_function_after_the_backends_loaded():
    code = (
        "import tsdb_service.storage.duckdb.store, tsdb_service.storage.postgres.store\n"
        "import tsdb_service.storage as s\n"
        "assert callable(s.migrate), type(s.migrate)\n"
        "from tsdb_service.storage import migrate\n"
        "assert callable(migrate)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
