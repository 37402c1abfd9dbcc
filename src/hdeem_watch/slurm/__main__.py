"""``python3 -m hdeem_watch.slurm prolog|epilog|nodes`` (the SLURM hooks; docs/slurm.md)."""

import sys

from hdeem_watch.slurm.hooks import main

sys.exit(main())
