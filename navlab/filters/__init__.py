"""Filter families. Each module registers its filters in :data:`FILTERS` (navlab.registry), which
imports every module of this package on first use.
"""

from navlab.filters.base import (
    FILTERS,
    Filter,
    KFState,
    LinearModel,
    Model,
    SideInfo,
    StepOut,
    get_filter_class,
    is_oracle,
    make_filter,
    register,
    registry,
)

__all__ = [
    "FILTERS",
    "Filter",
    "KFState",
    "LinearModel",
    "Model",
    "SideInfo",
    "StepOut",
    "get_filter_class",
    "is_oracle",
    "make_filter",
    "register",
    "registry",
]
