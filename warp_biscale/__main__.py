"""`python -m warp_biscale …` runs the command line, as `warp-biscale …` does."""

import sys

from .cli import main

sys.exit(main())
