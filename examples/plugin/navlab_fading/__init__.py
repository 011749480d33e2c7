"""A fading-memory Kalman filter for navlab: the filter and its plain reference."""

from navlab_fading import filter, reference  # noqa: F401 - both register themselves with navlab
