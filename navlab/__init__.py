"""navlab: learn, compare and trust robust and adaptive Kalman filters for navigation."""

import logging

__version__ = "0.1.0"

logging.getLogger("navlab").addHandler(logging.NullHandler())


def __getattr__(name: str):
    # navlab.load_results without importing the engine on ``import navlab``
    if name == "load_results":
        from navlab.experiment import load_results

        return load_results
    raise AttributeError(f"module 'navlab' has no attribute {name!r}")
