"""``python -m fleet`` is the ``plc-runtime`` command."""

import sys

from .console import main

sys.exit(main())
