import sys

from tsdb_service.cli import main

sys.exit(main())
