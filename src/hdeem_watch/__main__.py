"""``python -m hdeem_watch`` runs the command line."""

import sys

from hdeem_watch.cli import main

sys.exit(main())
