"""The scenario interface, the simulated data every filter sees, and the scenario registry.

A scenario turns (its parameters, a noise schedule, an outlier model, run indices, a base seed)
into :class:`ScenarioData`: truth, measurements, the true R(t), the outlier mask and the nominal
model the filters assume. Run r draws from independent truth / measurement / initial-estimate
(/ auxiliary) streams laid out by blocks of runs (:class:`RunStream`), so run r is the same whether
it is simulated alone, in a chunk or in a batch, and changing the outlier model does not change the
truth.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import numpy as np

from navlab import params as P_
from navlab.filters.base import Model, SideInfo
from navlab.jit import Kernel, carray
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
            parts[0], **{f: concat_runs([getattr(p, f) for p in parts]) for f in parts[0].PER_RUN}
        )


def concat_runs(arrays: Sequence[Array]) -> Array:
    """Arrays (B_i, …) joined along the runs, in the memory layout of the first: epoch-major
    ((B, K+1, …) views of (K+1, B, …) arrays: the truth of :func:`propagate`, the recorded
    estimates) stays epoch-major, anything else is concatenated as usual.
    """
    a0 = arrays[0]
    if a0.ndim >= 2 and a0.shape[0] > 1 and a0.swapaxes(0, 1).flags.c_contiguous:
        return np.concatenate([a.swapaxes(0, 1) for a in arrays], axis=1).swapaxes(0, 1)
    return np.concatenate(arrays)


BLOCK_RUNS = 64
"""Runs per random block. Part of the stream layout: changing it changes every number drawn."""

STREAMS = ("truth", "meas", "init", "aux")
"""The independent random streams of a run, by their index in the stream layout."""


class _Blocks:
    """Which blocks of :data:`BLOCK_RUNS` runs a batch touches, and where each block's rows go."""

    def __init__(self, runs: Sequence[int] | Array) -> None:
        r = np.asarray(runs)
        if r.ndim != 1 or (r.size and (r.dtype.kind not in "iu" or r.min() < 0)):
            raise ValueError(f"runs must be a 1-D sequence of run indices ≥ 0, got {runs!r}")
        self.runs = r.astype(np.int64)
        ids, inverse, counts = np.unique(self.runs // BLOCK_RUNS, return_inverse=True, return_counts=True)
        self.ids = [int(b) for b in ids]
        # per block: the rows of the batch it fills and those rows' places in the block
        self.rows_cols: list[tuple[slice | Array, Array]] = []
        groups = np.split(np.argsort(inverse, kind="stable"), np.cumsum(counts)[:-1]) if ids.size else []
        for b, rows in zip(self.ids, groups, strict=True):
            cols = self.runs[rows] - b * BLOCK_RUNS
            if (
                rows.size == BLOCK_RUNS
                and rows[-1] - rows[0] == BLOCK_RUNS - 1
                and (np.diff(cols) == 1).all()
                and cols[0] == 0
            ):
                rows = slice(int(rows[0]), int(rows[-1]) + 1)  # the whole block in order: in place
            self.rows_cols.append((rows, cols))


class RunStream:
    """One random stream of a batch of Monte Carlo runs; run r gets the same numbers in any batch.

    The stream layout (replacing ALGORITHMS.md §0.2 rule 6's generator per run, whose set-up per
    run and per stream before any draw was most of a large Monte Carlo): run indices are grouped in
    fixed blocks of :data:`BLOCK_RUNS` (runs 0–63, 64–127, …); stream s of block b draws from its
    own generator ``Generator(PCG64(SeedSequence(seed, spawn_key=(s, b))))``. Every draw is made
    for the WHOLE block — shape ``(BLOCK_RUNS, *shape)``, run j of the block in row j — and the
    rows of the requested runs are returned, so run r's numbers depend only on the seed, the
    stream, r and the sequence of draws made on the stream, never on the other runs of the batch
    (chunked Monte Carlo is invisible). A scenario must therefore make the same sequence of draws
    (methods and per-run shapes) whatever the runs: shapes may depend on its parameters only.

    numpy's own samplers are used unchanged (ziggurat normals, chi-square), so each block costs
    one generator instead of one per run, and draws run at numpy's full speed.

    Parameters
    ----------
    seed : base seed of the experiment.
    runs : run indices r ≥ 0 of the batch (any order, repeats allowed).
    stream : index of the stream in :data:`STREAMS`.
    """

    def __init__(
        self, seed: int, runs: Sequence[int] | Array, stream: int, layout: _Blocks | None = None
    ) -> None:
        self.seed, self.stream = int(seed), int(stream)
        self._layout = layout if layout is not None else _Blocks(runs)
        self.runs = self._layout.runs
        self._gens: list[np.random.Generator] | None = None

    def __len__(self) -> int:
        return int(self.runs.size)

    def _generators(self) -> list[np.random.Generator]:
        if self._gens is None:  # created on first use: a stream a scenario never draws costs nothing
            self._gens = [
                np.random.Generator(
                    np.random.PCG64(np.random.SeedSequence(self.seed, spawn_key=(self.stream, b)))
                )
                for b in self._layout.ids
            ]
        return self._gens

    def _draw(self, method: str, shape: tuple[int, ...] | int, *args: float) -> Array:
        shape = (int(shape),) if np.isscalar(shape) else tuple(int(s) for s in shape)
        out = np.empty((len(self), *shape))
        size = (BLOCK_RUNS, *shape)
        for gen, (rows, cols) in zip(self._generators(), self._layout.rows_cols, strict=True):
            sample = getattr(gen, method)
            if not isinstance(rows, slice):
                out[rows] = sample(*args, size=size)[cols]
            elif method in ("standard_normal", "random"):  # the whole block in order: in place
                sample(out=out[rows])
            else:
                out[rows] = sample(*args, size=size)
        return out

    def standard_normal(self, shape: tuple[int, ...] | int) -> Array:
        """N(0, 1) draws, (B, *shape): ``Generator.standard_normal`` per block."""
        return self._draw("standard_normal", shape)

    def random(self, shape: tuple[int, ...] | int) -> Array:
        """U[0, 1) draws, (B, *shape): ``Generator.random`` per block."""
        return self._draw("random", shape)

    def chisquare(self, df: float, shape: tuple[int, ...] | int) -> Array:
        """χ²(df) draws, (B, *shape): ``Generator.chisquare`` per block."""
        return self._draw("chisquare", shape, float(df))


@dataclass(frozen=True, eq=False)
class RunStreams:
    """The independent random streams of a batch of runs (see :class:`RunStream`).

    ``truth`` (the simulated truth), ``meas`` (measurement noise and outliers), ``init`` (initial
    estimates) and ``aux`` (a scenario's other draws, e.g. GPS gross errors), so changing the
    outlier model does not change the truth. ``len(streams)`` is the number of runs B.
    """

    truth: RunStream
    meas: RunStream
    init: RunStream
    aux: RunStream

    def __len__(self) -> int:
        return len(self.truth)


def run_streams(seed: int, runs: Sequence[int] | Array) -> RunStreams:
    """The random streams of the runs ``runs`` (each run's numbers independent of the batch)."""
    layout = _Blocks(runs)
    return RunStreams(*(RunStream(seed, runs, s, layout) for s in range(len(STREAMS))))


def _propagate_runs(x0, Phi, e, L, u, has_u, x):  # pragma: no cover - compiled by numba
    """x_k = Φ_k x_{k−1} + L_k e_k (+ u_k) for every run (textbook loops, one run at a time).

    Epoch-major arrays: x (K+1, B, n), e (K, B, n_e), u (K, B, n); Phi (1 or K+1, n, n) and
    L (1 or K+1, n, n_e): one matrix for every epoch, or one per epoch. Each sum runs over j in
    order from the first product, then (Φx) + (Le) + u: the numpy path makes the same operations
    in the same order.
    """
    K, B, ne = e.shape
    n = x0.shape[1]
    for r in range(B):
        for i in range(n):
            x[0, r, i] = x0[r, i]
    for k in range(1, K + 1):
        F = Phi[k] if Phi.shape[0] > 1 else Phi[0]
        G = L[k] if L.shape[0] > 1 else L[0]
        for r in range(B):
            for i in range(n):
                a = 0.0
                for j in range(n):
                    a += F[i, j] * x[k - 1, r, j]
                b = 0.0
                for j in range(ne):
                    b += G[i, j] * e[k - 1, r, j]
                x[k, r, i] = a + b + u[k - 1, r, i] if has_u else a + b


_PROPAGATE = Kernel(_propagate_runs)

#: per-run multiply-adds K·n·(n + n_e) from which the compiled path is used (the 15-state INS
#: models: ≈ 4·10⁵); below it, numpy in the same order of operations is as fast and needs no numba
COMPILED_FROM_MACS = 100_000


def _matvec_in_order(A: Array, X: Array) -> Array:
    """Columns X[:, r] ↦ A X[:, r], (n_in, B) → (n, B); each sum over j in order from the first
    product, elementwise (no BLAS), so run r's result does not depend on the other columns.
    """
    y = A[:, 0:1] * X[0]
    for j in range(1, A.shape[1]):
        y += A[:, j : j + 1] * X[j]
    return y


def _propagate_numpy(x0: Array, Phi: Array, e: Array, L: Array, u: Array | None) -> Array:
    """The numpy path of :func:`_propagate_runs`: the same operations, every run at once per
    epoch in a (K+1, n, B) layout (contiguous rows of B runs).
    """
    B, K = e.shape[:2]
    n = x0.shape[1]
    xt = np.empty((K + 1, n, B))
    xt[0] = x0.T
    et = np.ascontiguousarray(e.transpose(1, 2, 0))  # (K, n_e, B)
    ut = None if u is None else np.ascontiguousarray(u.transpose(1, 2, 0))
    for k in range(1, K + 1):
        F = Phi[k] if Phi.shape[0] > 1 else Phi[0]
        G = L[k] if L.shape[0] > 1 else L[0]
        y = _matvec_in_order(F, xt[k - 1])
        y += _matvec_in_order(G, et[k - 1])
        if ut is not None:
            y += ut[k - 1]
        xt[k] = y
    return np.ascontiguousarray(xt.transpose(0, 2, 1)).swapaxes(0, 1)  # epoch-major (see propagate)


def propagate(x0: Array, Phi: Array, e: Array, L: Array | None = None, u: Array | None = None) -> Array:
    """The truth of a linear model in every run: x_k = Φ_k x_{k−1} + L_k e_k (+ u_k), k = 1 … K.

    Run r's result is the same bits whatever the other runs of the batch (a fixed order of every
    sum, no BLAS), so chunked Monte Carlo is invisible. Long recursions (≥
    :data:`COMPILED_FROM_MACS` multiply-adds per run) run compiled (:mod:`navlab.jit`) when numba
    is available; otherwise numpy, batched over the runs, makes the same operations in the same
    order (the same bits, tested).

    Parameters
    ----------
    x0 : (B, n) or (n,) initial states.
    Phi : (n, n), or (K+1, n, n) with Phi[k] the transition k−1 → k (Phi[0] unused).
    e : (B, K, n_e) driving noise; e[:, k−1] drives the transition k−1 → k.
    L : None (L_k = I, n_e = n), (n, n_e), or (K+1, n, n_e) with L[k] for k−1 → k (L[0] unused).
    u : None or (B, K, n), a further additive term; u[:, k−1] is added at epoch k.

    Returns
    -------
    x : (B, K+1, n), x[:, 0] = x0: a view of an epoch-major (K+1, B, n) array, the layout in which
        the experiment records the filters' estimates (navlab.experiment._Recorder), so the
        estimation errors are computed without a transposing copy.
    """
    e = np.asarray(e, dtype=float)
    B, K, ne = e.shape
    Phi = np.asarray(Phi, dtype=float)
    n = Phi.shape[-1]
    L = np.eye(n) if L is None else np.asarray(L, dtype=float)
    Phi3 = carray(Phi if Phi.ndim == 3 else Phi[None])
    L3 = carray(L if L.ndim == 3 else L[None])
    x0 = carray(np.broadcast_to(np.asarray(x0, dtype=float), (B, n)))
    u = None if u is None else np.asarray(u, dtype=float)
    kernel = _PROPAGATE.get() if K * n * (n + ne) >= COMPILED_FROM_MACS else None
    if kernel is None:
        return _propagate_numpy(x0, Phi3, e, L3, u)
    xt = np.empty((K + 1, B, n))  # epoch-major: Φ_k, L_k and x_{k−1} of every run in cache
    ut = np.zeros((1, B, n)) if u is None else carray(u.transpose(1, 0, 2))
    kernel(x0, Phi3, carray(e.transpose(1, 0, 2)), L3, ut, u is not None, xt)
    return xt.swapaxes(0, 1)


def draw_measurement_noise(
    streams: RunStreams, std: Array, outliers: OutlierModel
) -> tuple[Array, Array, Array, Array]:
    """Noise of every run from the measurement stream: (noise, var, bias, mask), each (B, K+1, m)."""
    return tuple(np.ascontiguousarray(a) for a in outliers.draw(streams.meas, std))


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
    #: how :mod:`navlab.pcrb` bounds the scenario: "linear" (exact: the truth is drawn from the
    #: linear model the filters assume, the noise from the outlier model), "monte-carlo" (linear
    #: dynamics, nonlinear measurements: their information averaged over the simulated truth),
    #: "" (no bound: the truth or the noise is drawn from something no outlier model states)
    pcrb: ClassVar[str] = ""

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

    def noise_models(self, schedule: Schedule, outliers: OutlierModel) -> tuple[Schedule, OutlierModel]:
        """The schedule and outlier model :meth:`simulate` draws the noise with (a scenario's
        preset case may replace the chosen ones).
        """
        return schedule, outliers


#: Every scenario, by key; the modules of :mod:`navlab.scenarios` register theirs.
SCENARIOS: Registry[type[Scenario]] = Registry(
    "scenario", package="navlab.scenarios", plugins="navlab.scenarios"
)

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
