"""``python -m radiopose`` runs the command line."""

import sys

from radiopose.cli import main

sys.exit(main())
