"""The contract tests' cases as pytest parameters; the data, driver and checks are navlab.contracts.

The cases come from the registries (plugins included), so a new filter or scenario is checked
without touching a test. A :class:`~navlab.contracts.ContractSkipped` raised by a check is a pytest
skip (tests/contract/conftest.py).
"""

from __future__ import annotations

import pytest

from navlab.contracts import (
    RUNS,
    SLOW_REFERENCES,
    Run,
    assert_same_estimates,
    batched_P,
    cached_run,
    cases,
    compatible,
    drive,
    filter_for,
    scenario_data,
    state_sigma,
)

CASES = [pytest.param(f, s, id=f"{f}@{s}") for f, s in cases()]

__all__ = [
    "CASES",
    "RUNS",
    "SLOW_REFERENCES",
    "Run",
    "assert_same_estimates",
    "batched_P",
    "cached_run",
    "compatible",
    "drive",
    "filter_for",
    "scenario_data",
    "state_sigma",
]
