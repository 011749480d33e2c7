"""Scenarios: simulated experiments of the four papers and the real-data recordings.

Importing this package imports (and so registers) every module in it.
"""

import importlib
import pkgutil

from navlab.scenarios.base import (
    MetricGroup,
    Scenario,
    ScenarioData,
    get_scenario_class,
    make_scenario,
    register_scenario,
    scenario_registry,
)

__all__ = [
    "MetricGroup",
    "Scenario",
    "ScenarioData",
    "get_scenario_class",
    "make_scenario",
    "register_scenario",
    "scenario_registry",
]

# every module of this package registers its scenarios on import
for _m in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_m.name}")
