"""Scenarios: simulated experiments of the four papers and the real-data recordings.

Importing this package registers every scenario module listed below.
"""

from navlab.scenarios import cv2d  # noqa: F401
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
    "MetricGroup", "Scenario", "ScenarioData", "get_scenario_class", "make_scenario",
    "register_scenario", "scenario_registry",
]
