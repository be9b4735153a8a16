"""``python -m tmcl_server.tool`` is ``tmcl``."""

import sys

from tmcl_server.tool import main

sys.exit(main())
