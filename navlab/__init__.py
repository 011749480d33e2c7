"""navlab: learn, compare and trust robust and adaptive Kalman filters for navigation."""

import logging

__version__ = "0.1.0"

logging.getLogger("navlab").addHandler(logging.NullHandler())
