"""Scenarios: simulated experiments of the four papers and the real-data recordings.

Each module registers its scenarios in :data:`SCENARIOS` (navlab.registry), which imports every
module of this package on first use.
"""

from navlab.scenarios.base import (
    SCENARIOS,
    MetricGroup,
    Scenario,
    ScenarioData,
    get_scenario_class,
    make_scenario,
    register_scenario,
    scenario_registry,
)

__all__ = [
    "SCENARIOS",
    "MetricGroup",
    "Scenario",
    "ScenarioData",
    "get_scenario_class",
    "make_scenario",
    "register_scenario",
    "scenario_registry",
]
