"""``python -m mipnet.bench ops|model``."""

import sys

from .ops import main

sys.exit(main())
