"""``python -m popbench`` runs the command line (see :mod:`popbench.cli`)."""

import sys

from popbench.cli import main

sys.exit(main())
