"""``python -m vprsnn_export``: the same as the ``vprsnn-export`` command."""

import sys

from .cli import main

sys.exit(main())
