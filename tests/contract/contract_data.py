"""Shared data and drivers of the contract tests: every registered filter × every compatible scenario.

The cases come from the registries, so a new filter or scenario is checked without touching a test.
Each scenario is simulated once per session (3 runs, a few epochs) in three variants: ``normal``
(the scenario's default outliers), ``clean`` (no outliers: the KF limits) and ``gappy`` (normal plus
missing channels and a missing epoch). Every filter run happens with RuntimeWarnings as errors and
numpy's floating-point errors as warnings, so a NaN or overflow inside a filter fails the test.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pytest

from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec, plan
from navlab.filters import StepOut, make_filter, registry
from navlab.scenarios import ScenarioData, scenario_registry

RUNS = 3
SEED = 7
EPOCHS = {"drive0708": 6, "gps-ins-rtk": 10}  # default: 10 (few epochs: the contracts are per step)
EPOCHS_DEFAULT = 10


def _epochs(scenario: str) -> int:
    return EPOCHS.get(scenario, EPOCHS_DEFAULT)


@functools.cache
def scenario_data(scenario: str, variant: str) -> ScenarioData:
    """The scenario's batch (RUNS runs) in a variant: normal, clean or gappy."""
    outliers = "none" if variant == "clean" else "mixture"
    try:
        p = plan(
            ExperimentSpec(
                scenario=scenario, filters=("kf",), runs=RUNS, epochs=_epochs(scenario), outliers=outliers
            )
        )
        data = p.scenario.simulate(p.schedule, p.outliers, range(RUNS), SEED)
    except NavlabError as exc:  # a real recording that is not on this machine
        pytest.skip(f"scenario {scenario} unavailable: {exc}")
    if variant == "gappy":
        z = data.z.copy()
        z[:, 2, 0] = np.nan  # a missing channel in every run
        z[1, 3, :] = np.nan  # a missing epoch in one run
        z[2, 4, -1] = np.nan
        data = replace(data, z=z)
    return data


def compatible(fkey: str, scenario: str) -> str | None:
    """Why filter ``fkey`` cannot run on ``scenario`` (None if it can)."""
    fcls, scls = registry()[fkey], scenario_registry()[scenario]
    if fcls.family == "oracle" and not scls.simulated:
        return "needs simulator ground truth"
    return None


# (filter, scenario) cases whose plain reference (tests/contract/test_reference.py) takes seconds:
# the skew-t reference computes scipy's truncated-normal moments per channel and VB iteration, on
# smartloc-berlin's 20 satellites 11–35 s on this 2-core machine. tests/contract/conftest.py marks
# them slow (the full suite runs them; the not-slow edit loop keeps every other case).
SLOW_REFERENCES = {("skew-t-kf", "smartloc-berlin")}

CASES = [
    pytest.param(f, s, id=f"{f}@{s}")
    for f in registry()
    for s in scenario_registry()
    if compatible(f, s) is None
]


def filter_for(fkey: str, scenario: str, params: dict[str, Any] | None = None):
    """The filter with the scenario's presets (as an experiment builds it) and ``params`` over them."""
    fp = {**scenario_registry()[scenario].filter_defaults.get(fkey, {}), **(params or {})}
    return make_filter(fkey, fp)


@dataclass
class Run:
    """Step outputs (epochs 1 … K) and the states after each update."""

    outs: list[StepOut]
    states: list[Any]


def drive(f, data: ScenarioData, runs=slice(None), model=None, z=None, epochs: int | None = None) -> Run:
    """The shared time loop for one filter, RuntimeWarnings (numpy FP errors included) as errors."""
    model = model if model is not None else data.model
    z = data.z if z is None else z
    K = data.K if epochs is None else epochs
    outs, states = [], []
    with warnings.catch_warnings(), np.errstate(divide="warn", over="warn", invalid="warn", under="ignore"):
        warnings.simplefilter("error", RuntimeWarning)
        try:
            st = f.init(model, data.x0[runs], data.P0)
        except NavlabError as exc:  # the filter refuses this model (e.g. a correlated R)
            pytest.skip(f"{f.key} refuses this model: {exc}")
        for k in range(1, K + 1):
            st = f.predict(model, st, k)
            st, out = f.update(model, st, k, z[runs, k], data.side(k, runs))
            outs.append(out)
            states.append(st)
    return Run(outs, states)


@functools.cache
def cached_run(fkey: str, scenario: str, variant: str) -> Run:
    """The filter (scenario presets) over the whole batch of a data variant, run once per session."""
    return drive(filter_for(fkey, scenario), scenario_data(scenario, variant))


def batched_P(P: np.ndarray, B: int) -> np.ndarray:
    return np.broadcast_to(P, (B, *np.shape(P)[-2:]))


def state_sigma(run: Run, B: int) -> np.ndarray:
    """(K, B, n) posterior standard deviations."""
    return np.sqrt(np.abs(np.stack([np.diagonal(batched_P(o.P, B), axis1=-2, axis2=-1) for o in run.outs])))


def assert_same_estimates(a: Run, b: Run, B: int, rel: float, what: str) -> None:
    """x equal to ``rel`` of the posterior σ (plus rel·|x|), P equal to ``rel`` relative."""
    xa, xb = np.stack([o.x for o in a.outs]), np.stack([o.x for o in b.outs])
    sig = state_sigma(b, B)
    err = np.abs(xa - xb) / (sig + np.abs(xb) + 1e-300)
    assert np.all(err <= rel), f"{what}: x differs by {np.nanmax(err):.2e} of σ (tolerance {rel:g})"
    Pa = np.stack([batched_P(o.P, B) for o in a.outs])
    Pb = np.stack([batched_P(o.P, B) for o in b.outs])
    d = np.sqrt(np.abs(np.diagonal(Pb, axis1=-2, axis2=-1)))
    scale = d[..., :, None] * d[..., None, :] + 1e-300
    perr = np.abs(Pa - Pb) / scale
    assert np.all(perr <= rel), f"{what}: P differs by {np.nanmax(perr):.2e} relative (tolerance {rel:g})"
