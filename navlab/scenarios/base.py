"""The scenario interface, the simulated data every filter sees, and the scenario registry.

A scenario turns (its parameters, a noise schedule, an outlier model, run indices, a base seed)
into :class:`ScenarioData`: truth, measurements, the true R(t), the outlier mask and the nominal
model the filters assume. Run r always draws from ``SeedSequence([seed, r])`` (split into
independent truth / measurement / initial-estimate streams), so run r is the same whether it is
simulated alone or in a batch, and changing the outlier model does not change the truth.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import numpy as np

from navlab import params as P_
from navlab.filters.base import Model, SideInfo
from navlab.linalg import Array
from navlab.noise import OutlierModel, Schedule
from navlab.registry import Registry


class MetricGroup(NamedTuple):
    """A group of state components reported together (error norm over ``idx``).

    ``scale`` converts state units to display units (e.g. rad → arcmin).
    """

    idx: tuple[int, ...]
    unit: str
    label: str
    scale: float = 1.0


@dataclass(eq=False)
class ScenarioData:
    """Everything one experiment's filters see and are judged against. Arrays (B, K+1, …).

    Index 0 is the initial epoch: ``z[:, 0]`` is NaN (no measurement).
    """

    scenario: str
    t: Array  # (K+1,) seconds
    model: Model
    x_true: Array  # (B, K+1, n)
    z: Array  # (B, K+1, m); NaN = channel unavailable
    R_true: Array  # (B, K+1, m) variance actually drawn (contamination included)
    R_schedule: Array  # (K+1, m) variance of the noise schedule (the "true R(t)")
    outlier_mask: Array  # (B, K+1, m) bool
    bias: Array  # (B, K+1, m) known additive outlier mean
    x0: Array  # (B, n) initial estimate
    P0: Array  # (n, n)
    runs: Array  # (B,) run indices r
    state_names: tuple[str, ...]
    channel_names: tuple[str, ...]
    channel_units: tuple[str, ...]
    groups: dict[str, MetricGroup]
    window: Array  # (K+1,) bool: default analysis window
    Q_extra: Array | None = None  # (K+1, n, n) process-noise anomaly known to the oracle
    has_truth: bool = True
    extras: dict[str, Any] = field(default_factory=dict)
    # position-error bound (m, on the "pos" group) of the divergence rule; None: 100 × the
    # largest nominal measurement σ (navlab.metrics.divergence_bound)
    divergence_bound: float | None = None

    @property
    def B(self) -> int:
        return int(self.z.shape[0])

    @property
    def K(self) -> int:
        return int(self.z.shape[1] - 1)

    def side(self, k: int, sl: slice | Array = slice(None)) -> SideInfo:
        """Simulator side information at epoch k (for the oracle), for the runs ``sl``."""
        return SideInfo(
            R_true=self.R_true[sl, k],
            bias=self.bias[sl, k],
            outlier=self.outlier_mask[sl, k],
            Q_extra=None if self.Q_extra is None else self.Q_extra[k],
        )

    # the fields with a leading run axis (everything else is shared by every run)
    PER_RUN: ClassVar[tuple[str, ...]] = ("x_true", "z", "R_true", "outlier_mask", "bias", "x0", "runs")

    def subset(self, sl: slice) -> ScenarioData:
        """The same data for a slice of runs (chunked Monte Carlo)."""
        return dataclasses.replace(self, **{f: getattr(self, f)[sl] for f in self.PER_RUN})

    @staticmethod
    def concat(parts: Sequence[ScenarioData]) -> ScenarioData:
        """The data of consecutive chunks of runs as one."""
        if len(parts) == 1:
            return parts[0]
        return dataclasses.replace(
            parts[0], **{f: np.concatenate([getattr(p, f) for p in parts]) for f in parts[0].PER_RUN}
        )


class RunStreams(NamedTuple):
    """Independent random streams of one Monte Carlo run."""

    truth: np.random.Generator
    meas: np.random.Generator
    init: np.random.Generator


def run_streams(seed: int, r: int) -> RunStreams:
    """The three generators of run r: ``SeedSequence([seed, r]).spawn(3)`` (ALGORITHMS.md §0.2)."""
    children = np.random.SeedSequence([int(seed), int(r)]).spawn(3)
    return RunStreams(*(np.random.default_rng(c) for c in children))


def draw_measurement_noise(
    streams: Sequence[RunStreams], std: Array, outliers: OutlierModel
) -> tuple[Array, Array, Array, Array]:
    """Noise of every run from its measurement stream: (noise, var, bias, mask), each (B, K+1, m)."""
    draws = [outliers.draw(s.meas, std) for s in streams]
    return tuple(np.stack([getattr(d, f) for d in draws]) for f in ("noise", "var", "bias", "mask"))


class Scenario:
    """Base class of simulated (and real-data) scenarios.

    Class attributes: ``key``, ``label``, ``paper``, ``summary``, ``Params`` (frozen dataclass),
    ``outlier_defaults`` (per outlier-model key, parameter overrides suited to this scenario),
    ``filter_defaults`` (per filter key, the same for filter parameters: e.g. per-channel χ²
    gating where one epoch holds many independent channels), ``default_filters``,
    ``simulated`` (False for real data: no oracle, no schedules).
    """

    key: ClassVar[str] = ""
    label: ClassVar[str] = ""
    paper: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    Params: ClassVar[type] = P_.NoParams
    outlier_defaults: ClassVar[dict[str, dict[str, Any]]] = {}
    filter_defaults: ClassVar[dict[str, dict[str, Any]]] = {}
    default_filters: ClassVar[tuple[str, ...]] = ("kf", "oracle-kf", "chi2-kf")
    default_runs: ClassVar[int] = 100
    simulated: ClassVar[bool] = True
    headline: ClassVar[tuple[str, ...]] = ("pos",)

    def __init__(self, params: Any = None) -> None:
        if params is None or isinstance(params, dict):
            params = P_.build(self.Params, params, f"scenario '{self.key}'")
        self.params = params

    @property
    def epochs(self) -> int:
        return int(getattr(self.params, "epochs", 0))

    def simulate(
        self, schedule: Schedule, outliers: OutlierModel, runs: Sequence[int], seed: int
    ) -> ScenarioData:
        raise NotImplementedError


#: Every scenario, by key; the modules of :mod:`navlab.scenarios` register theirs.
SCENARIOS: Registry[type[Scenario]] = Registry("scenario", package="navlab.scenarios")

#: Class decorator adding a scenario to :data:`SCENARIOS`.
register_scenario = SCENARIOS.register


def scenario_registry() -> dict[str, type[Scenario]]:
    """All registered scenarios by key (a copy of :data:`SCENARIOS`)."""
    return dict(SCENARIOS)


def get_scenario_class(key: str) -> type[Scenario]:
    """The scenario class registered as ``key``; NavlabError naming the known keys otherwise."""
    return SCENARIOS.lookup(key)


def make_scenario(key: str, params: dict[str, Any] | None = None) -> Scenario:
    """Instantiate a registered scenario with validated parameters."""
    return SCENARIOS.make(key, params)
