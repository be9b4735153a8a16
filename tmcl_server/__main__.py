import sys

from tmcl_server.cli import main

sys.exit(main())
