"""``python -m senerf.bench`` = ``senerf-bench``."""

import sys

from .cli import main

sys.exit(main())
