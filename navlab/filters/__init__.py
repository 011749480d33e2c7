"""Filter families. Importing this package imports (and so registers) every module in it."""

import importlib
import pkgutil

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
    "Filter",
    "KFState",
    "LinearModel",
    "Model",
    "SideInfo",
    "StepOut",
    "get_filter_class",
    "make_filter",
    "register",
    "registry",
]

# every module of this package registers its filters with @register on import
for _m in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_m.name}")
