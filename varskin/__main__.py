"""``python -m varskin`` is the same as the ``varskin`` command."""

import sys

from varskin.cli import main

sys.exit(main())
