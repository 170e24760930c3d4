import sys

from tsdb_service.cli.main import main

sys.exit(main())
