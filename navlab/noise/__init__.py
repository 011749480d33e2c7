"""Noise schedules (true R(t)) and outlier models (contamination), shared by every scenario."""

from navlab.noise.outliers import OUTLIERS, NoiseDraw, OutlierModel, make_outliers
from navlab.noise.schedules import SCHEDULES, Schedule, make_schedule

__all__ = [
    "OUTLIERS",
    "SCHEDULES",
    "NoiseDraw",
    "OutlierModel",
    "Schedule",
    "make_outliers",
    "make_schedule",
]
