"""Experiments: a frozen spec -> simulated data -> every filter over the same batch -> records.

:class:`ExperimentSpec` is the single description of a run: the cache key in the app, the
``--config`` file of the CLI, the downloadable JSON and the content of a shared URL.
:func:`run_filters` is the one time loop that drives every filter over one batch of runs;
:func:`iter_experiment` runs the Monte Carlo in chunks of runs and yields partial results (the
app streams them), :func:`run_experiment` returns the final :class:`Results`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from navlab.errors import NavlabError
from navlab.filters.base import Filter, get_filter_class, make_filter
from navlab.linalg import Array, diag, quad
from navlab.noise import OUTLIERS, make_outliers, make_schedule
from navlab.scenarios.base import Scenario, ScenarioData, get_scenario_class

MAX_RUNS = 20000
MAX_EPOCHS = 200000


def _freeze(d: Mapping[str, Any] | None) -> dict[str, Any]:
    return json.loads(json.dumps(dict(d or {}), sort_keys=True))


@dataclass(frozen=True)
class ExperimentSpec:
    """Everything that defines a run; JSON round-trips; equal specs give identical numbers.

    Attributes
    ----------
    scenario : registry key of the scenario.
    filters : registry keys of the filters, in display order.
    runs, seed : Monte Carlo size and base seed (run r uses SeedSequence([seed, r])).
    epochs : number of epochs K (None: the scenario's default).
    noise_schedule, noise_params : the true R(t) schedule and its parameters.
    outliers, outlier_params : outlier model and its parameters (over the scenario's defaults).
    contamination, outlier_scale : shortcuts for the outlier model's ``contamination`` and
        ``scale`` parameters (None: keep the default).
    scenario_params : scenario parameters (over its defaults).
    filter_params : {filter key: {parameter: value}}.
    """

    scenario: str = "cv2d"
    filters: tuple[str, ...] = ("kf", "oracle-kf", "chi2-kf")
    runs: int = 100
    seed: int = 1
    epochs: int | None = None
    noise_schedule: str = "constant"
    noise_params: dict[str, Any] = field(default_factory=dict)
    outliers: str = "mixture"
    contamination: float | None = None
    outlier_scale: float | None = None
    outlier_params: dict[str, Any] = field(default_factory=dict)
    scenario_params: dict[str, Any] = field(default_factory=dict)
    filter_params: dict[str, dict[str, Any]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "filters", tuple(self.filters))
        for name in ("noise_params", "outlier_params", "scenario_params", "filter_params"):
            object.__setattr__(self, name, _freeze(getattr(self, name)))

    def __hash__(self) -> int:
        return hash(self.to_json())

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["filters"] = list(self.filters)
        return d

    def to_json(self, indent: int | None = None) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, indent=indent)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ExperimentSpec:
        """Build a spec from a mapping (a parsed JSON config); NavlabError on unknown keys/types."""
        if not isinstance(d, Mapping):
            raise NavlabError("a configuration must be a JSON object with keys such as 'scenario'")
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise NavlabError(
                f"unknown configuration key(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}"
            )
        d = dict(d)
        if "filters" in d:
            f = d["filters"]
            if isinstance(f, str):
                f = [s.strip() for s in f.split(",") if s.strip()]
            if not isinstance(f, (list, tuple)) or not all(isinstance(s, str) for s in f):
                raise NavlabError('\'filters\' must be a list of filter keys, e.g. ["kf", "chi2-kf"]')
            d["filters"] = tuple(f)
        for name in ("noise_params", "outlier_params", "scenario_params", "filter_params"):
            if name in d and not isinstance(d[name], Mapping):
                raise NavlabError(f"'{name}' must be a JSON object")
        if "filter_params" in d:
            for k, v in d["filter_params"].items():
                if not isinstance(v, Mapping):
                    raise NavlabError(f"'filter_params.{k}' must be a JSON object of parameters")
        return cls(**d)

    @classmethod
    def from_json(cls, text: str | bytes) -> ExperimentSpec:
        try:
            d = json.loads(text)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise NavlabError(f"the configuration is not valid JSON ({exc})") from None
        return cls.from_dict(d)

    def replace(self, **changes: Any) -> ExperimentSpec:
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class Plan:
    """A validated spec: the scenario, schedule, outlier model and filter objects to run."""

    spec: ExperimentSpec
    scenario: Scenario
    schedule: Any
    outliers: Any
    filters: tuple[Filter, ...]


def _check_int(name: str, value: Any, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise NavlabError(f"'{name}' must be a whole number, got {value!r}")
    if int(value) != value or not lo <= value <= hi:
        raise NavlabError(f"'{name}' must be a whole number in [{lo}, {hi}], got {value!r}")
    return int(value)


def plan(spec: ExperimentSpec) -> Plan:
    """Validate every part of ``spec`` before any computation; NavlabError says what to change."""
    _check_int("runs", spec.runs, 1, MAX_RUNS)
    _check_int("seed", spec.seed, 0, 2**63 - 1)
    scen_cls = get_scenario_class(spec.scenario)
    sp = dict(spec.scenario_params)
    if spec.epochs is not None:
        _check_int("epochs", spec.epochs, 2, MAX_EPOCHS)
        sp["epochs"] = int(spec.epochs)
    scenario = scen_cls(sp)
    if not spec.filters:
        raise NavlabError("choose at least one filter")
    if len(set(spec.filters)) != len(spec.filters):
        raise NavlabError("each filter may be chosen only once")
    unknown_fp = sorted(set(spec.filter_params) - set(spec.filters))
    if unknown_fp:
        raise NavlabError(f"filter_params names filter(s) not in the run: {', '.join(unknown_fp)}")
    filters = []
    for key in spec.filters:
        cls = get_filter_class(key)
        if cls.family == "oracle" and not scen_cls.simulated:
            raise NavlabError(
                f"'{key}' needs simulator ground truth; scenario '{spec.scenario}' is real data"
            )
        fp = {**scen_cls.filter_defaults.get(key, {}), **spec.filter_params.get(key, {})}
        filters.append(make_filter(key, fp))
    schedule = make_schedule(spec.noise_schedule, spec.noise_params)
    if spec.outliers not in OUTLIERS:
        raise NavlabError(f"unknown outlier model '{spec.outliers}'; known: {', '.join(OUTLIERS)}")
    op = dict(scen_cls.outlier_defaults.get(spec.outliers, {}))
    fields = {f.name for f in dataclasses.fields(OUTLIERS[spec.outliers].Params)}
    for name, value in (("contamination", spec.contamination), ("scale", spec.outlier_scale)):
        if value is not None:
            if name not in fields:
                raise NavlabError(
                    f"outlier model '{spec.outliers}' has no {name}; "
                    f"use --outliers mixture for a contamination ratio"
                )
            op[name] = value
    op.update(spec.outlier_params)
    outliers = make_outliers(spec.outliers, op)
    return Plan(spec, scenario, schedule, outliers, tuple(filters))


@dataclass(eq=False)
class FilterRun:
    """What one filter produced over a batch. Arrays are (B, K+1, …); epoch 0 is the prior."""

    key: str
    label: str
    x: Array
    P_diag: Array
    innov: Array
    S_diag: Array
    nis: Array
    nees: Array
    R_used: Array  # diagonal of the R in the gain
    R_hat: Array | None  # diagonal of the filter's R̂, if it estimates R
    weights: Array
    flags: Array
    stats: dict[str, Array]
    runtime_s: float
    diverged_at: Array  # (B,) first epoch with a non-finite state, −1 if never

    @property
    def diverged(self) -> Array:
        return self.diverged_at >= 0

    @staticmethod
    def concat(parts: Sequence[FilterRun]) -> FilterRun:
        first = parts[0]
        cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
        return FilterRun(
            key=first.key,
            label=first.label,
            x=cat("x"),
            P_diag=cat("P_diag"),
            innov=cat("innov"),
            S_diag=cat("S_diag"),
            nis=cat("nis"),
            nees=cat("nees"),
            R_used=cat("R_used"),
            R_hat=None if first.R_hat is None else cat("R_hat"),
            weights=cat("weights"),
            flags=cat("flags"),
            stats={k: np.concatenate([p.stats[k] for p in parts]) for k in first.stats},
            runtime_s=sum(p.runtime_s for p in parts),
            diverged_at=cat("diverged_at"),
        )


def _stack(arrays: Sequence[Any], shape: tuple[int, ...]) -> Array:
    """The per-epoch arrays stacked and broadcast to (L, *shape) (a read-only view may result).

    The usual case — every epoch's array has the same shape, e.g. a P shared by all runs — is one
    np.stack and one broadcast of the result (broadcast_to costs ≈ 10 µs of Python per call).
    """
    try:
        st = np.stack(arrays)
    except ValueError:  # shapes differ between epochs (a P that became per-run)
        return np.stack([a if np.shape(a) == shape else np.broadcast_to(a, shape) for a in arrays])
    if st.shape[1:] == shape:
        return st
    st = st.reshape((len(arrays),) + (1,) * (len(shape) + 1 - st.ndim) + st.shape[1:])
    return np.broadcast_to(st, (len(arrays), *shape))


class _Recorder:
    """Preallocated (B, K+1, …) arrays for one filter; fields appear on first use.

    Step outputs are buffered and written a block of epochs at a time: one stacked copy and one
    batched solve (NIS, NEES) per block instead of a dozen small numpy calls per epoch. The block
    is sized so the buffer stays within a few MB.
    """

    def __init__(self, f: Filter, data: ScenarioData) -> None:
        B, K1, n, m = data.B, data.K + 1, data.x0.shape[1], data.z.shape[2]
        self.f = f
        self.B, self.K1 = B, K1
        nan = lambda *s: np.full((B, K1, *s), np.nan)  # noqa: E731
        self.x, self.P_diag = nan(n), nan(n)
        self.x[:, 0] = data.x0
        self.P_diag[:, 0] = np.diagonal(data.P0)
        self.innov, self.S_diag, self.R_used = nan(m), nan(m), nan(m)
        self.R_hat = nan(m) if f.estimates_R else None
        self.nis, self.nees = nan(), nan()
        self.weights = np.ones((B, K1, m))
        self.flags = np.zeros((B, K1, m), dtype=np.int8)
        self.stats: dict[str, Array] = {}
        self.runtime = 0.0
        self.diverged_at = np.full(B, -1)
        self._pending: list[tuple[int, Any]] = []
        self.x_true = data.x_true if data.has_truth else None
        self._block = int(np.clip(4e6 / (8 * B * (n * n + m * m)), 1, 32))

    def put(self, k: int, out: Any) -> None:
        self._pending.append((k, out))
        if len(self._pending) >= self._block:
            self._flush()

    def _put_field(self, dest: Array, ks: Any, vals: list[Any], diagonal: bool = False) -> None:
        """Write per-epoch values (None: keep the default) into dest[:, k] for k in ks; with
        ``diagonal`` the values are matrices whose diagonal is written.
        """
        if all(v is not None for v in vals):
            shape = (
                (dest.shape[0], *dest.shape[2:], *dest.shape[-1:])
                if diagonal
                else (dest.shape[0], *dest.shape[2:])
            )
            st = _stack(vals, shape)
            if diagonal:
                st = np.diagonal(st, axis1=-2, axis2=-1)
            dest[:, ks] = st.swapaxes(0, 1)
            return
        for k, v in zip(range(dest.shape[1])[ks], vals, strict=True):
            if v is not None:
                dest[:, k] = diag(v) if diagonal else v

    def _flush(self) -> None:
        items, self._pending = self._pending, []
        if not items:
            return
        B = self.B
        ks: Any = [k for k, _ in items]
        if ks == list(range(ks[0], ks[-1] + 1)):
            ks = slice(ks[0], ks[-1] + 1)  # the usual case: a basic slice, not a fancy index
        outs = [o for _, o in items]
        n, m = self.x.shape[-1], self.innov.shape[-1]
        x = np.stack([o.x for o in outs], axis=1)  # (B, L, n)
        P = _stack([o.P for o in outs], (B, n, n))  # (L, B, n, n)
        Pd = np.diagonal(P, axis1=-2, axis2=-1).swapaxes(0, 1)
        self.x[:, ks] = x
        self.P_diag[:, ks] = Pd
        self.innov[:, ks] = np.stack([o.innov for o in outs], axis=1)
        S = _stack([o.S for o in outs], (B, m, m))
        self.S_diag[:, ks] = np.diagonal(S, axis1=-2, axis2=-1).swapaxes(0, 1)
        self._put_field(self.R_used, ks, [o.R_used for o in outs], diagonal=True)
        if self.R_hat is not None:
            self._put_field(self.R_hat, ks, [o.R_hat for o in outs], diagonal=True)
        self._put_field(self.weights, ks, [o.weights for o in outs])
        self._put_field(self.flags, ks, [o.flags for o in outs])
        for name in dict.fromkeys(s for o in outs for s in o.stats):
            vals = [o.stats.get(name) for o in outs]
            if name == "nis":
                self._put_field(self.nis, ks, vals)
                continue
            if name not in self.stats:
                v = np.asarray(next(v for v in vals if v is not None))
                self.stats[name] = np.full((B, self.K1, *v.shape[1:]), np.nan)
            self._put_field(self.stats[name], ks, vals)
        no_nis = [j for j, o in enumerate(outs) if "nis" not in o.stats]
        if no_nis:
            inn = np.stack([outs[j].innov for j in no_nis])
            self.nis[:, [items[j][0] for j in no_nis]] = quad(inn, S[no_nis]).T
        if self.x_true is not None:
            dx = (x - self.x_true[:, ks]).swapaxes(0, 1)
            self.nees[:, ks] = quad(dx, P).T
        ok = np.isfinite(x).all(axis=2) & np.isfinite(Pd).all(axis=2)  # (B, L)
        bad = ~ok.all(axis=1) & (self.diverged_at < 0)
        if bad.any():
            first = np.argmin(ok[bad], axis=1)
            self.diverged_at[bad] = np.asarray([k for k, _ in items])[first]

    def result(self) -> FilterRun:
        self._flush()
        f = self.f
        return FilterRun(
            key=f.key,
            label=f.label,
            x=self.x,
            P_diag=self.P_diag,
            innov=self.innov,
            S_diag=self.S_diag,
            nis=self.nis,
            nees=self.nees,
            R_used=self.R_used,
            R_hat=self.R_hat,
            weights=self.weights,
            flags=self.flags,
            stats=self.stats,
            runtime_s=self.runtime,
            diverged_at=self.diverged_at,
        )


def run_filters(
    data: ScenarioData,
    filters: Sequence[Filter],
    on_epoch: Callable[[int, int], None] | None = None,
) -> dict[str, FilterRun]:
    """Drive every filter through the same batch with ONE loop over epochs.

    At each epoch k = 1 … K every filter predicts (k−1 → k) and updates with the same z_k.
    """
    model = data.model
    states = [f.init(model, data.x0, data.P0) for f in filters]
    recs = [_Recorder(f, data) for f in filters]
    K = data.K
    # a run that blows up is caught by the recorder's finiteness check and reported as diverged
    # (left out of the metrics); it must not stop the other runs
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for k in range(1, K + 1):
            zk = data.z[:, k]
            side = data.side(k)
            for i, f in enumerate(filters):
                rec = recs[i]
                t0 = time.perf_counter()
                st = f.predict(model, states[i], k)
                states[i], out = f.update(model, st, k, zk, side)
                rec.runtime += time.perf_counter() - t0
                rec.put(k, out)
            if on_epoch is not None:
                on_epoch(k, K)
    return {f.key: r.result() for f, r in zip(filters, recs, strict=True)}


@dataclass(eq=False)
class Results:
    """The outcome of an experiment (possibly partial while a run streams)."""

    spec: ExperimentSpec
    data: ScenarioData
    runs: dict[str, FilterRun]
    complete: bool = True
    elapsed_s: float = 0.0

    @property
    def done_runs(self) -> int:
        return self.data.B

    def metrics(self):
        """Tidy metric table (pandas DataFrame): filter, metric, value, unit (see navlab.metrics)."""
        from navlab.metrics import summarize

        return summarize(self)


def _concat_data(parts: Sequence[ScenarioData]) -> ScenarioData:
    if len(parts) == 1:
        return parts[0]
    per_run = ("x_true", "z", "R_true", "outlier_mask", "bias", "x0", "runs")
    return dataclasses.replace(
        parts[0], **{f: np.concatenate([getattr(p, f) for p in parts]) for f in per_run}
    )


def iter_experiment(spec: ExperimentSpec, chunk_runs: int | None = None) -> Iterator[Results]:
    """Run the Monte Carlo in chunks of runs; yield the accumulated results after each chunk.

    Chunking never changes the numbers: run r draws from its own seed whatever the chunk.
    """
    p = plan(spec)
    total = spec.runs
    chunk = max(1, min(total, chunk_runs or total))
    data_parts: list[ScenarioData] = []
    run_parts: dict[str, list[FilterRun]] = {f.key: [] for f in p.filters}
    t_start = time.perf_counter()
    for start in range(0, total, chunk):
        runs = list(range(start, min(total, start + chunk)))
        data = p.scenario.simulate(p.schedule, p.outliers, runs, spec.seed)
        out = run_filters(data, p.filters)
        data_parts.append(data)
        for key, fr in out.items():
            run_parts[key].append(fr)
        done = runs[-1] + 1
        yield Results(
            spec=spec,
            data=_concat_data(data_parts),
            runs={k: FilterRun.concat(v) if len(v) > 1 else v[0] for k, v in run_parts.items()},
            complete=done >= total,
            elapsed_s=time.perf_counter() - t_start,
        )


def run_experiment(
    spec: ExperimentSpec,
    on_progress: Callable[[int, int], None] | None = None,
    chunk_runs: int | None = None,
) -> Results:
    """Run ``spec`` to completion; ``on_progress(done_runs, total_runs)`` after each chunk."""
    res = None
    for res in iter_experiment(spec, chunk_runs=chunk_runs):
        if on_progress is not None:
            on_progress(res.done_runs, spec.runs)
    assert res is not None
    return res
