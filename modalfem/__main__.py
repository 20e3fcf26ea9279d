"""``python -m modalfem``: the modalfem command line."""

import sys

from modalfem.cli import main

sys.exit(main())
