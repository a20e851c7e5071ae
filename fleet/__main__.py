"""``python -m fleet`` is the ``plc-runtime`` command."""

import sys

from .cli import main

sys.exit(main())
