"""``python -m mipnet.bench ops|model|precision``."""

import sys

from .ops import main

sys.exit(main())
