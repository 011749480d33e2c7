"""Filter families. Importing this package registers every filter module listed below."""

from navlab.filters import kalman  # noqa: F401
from navlab.filters.base import (
    Filter,
    KFState,
    LinearModel,
    Model,
    SideInfo,
    StepOut,
    get_filter_class,
    make_filter,
    register,
    registry,
)

__all__ = [
    "Filter", "KFState", "LinearModel", "Model", "SideInfo", "StepOut", "get_filter_class",
    "make_filter", "register", "registry",
]
