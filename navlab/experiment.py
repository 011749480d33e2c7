"""Experiments: a frozen spec -> simulated data -> every filter over the same batch -> records.

:class:`ExperimentSpec` is the single description of a run: the cache key in the app, the
``--config`` file of the CLI, the downloadable JSON and the content of a shared URL.
:func:`run_filters` is the one time loop that drives every filter over one batch of runs;
:func:`iter_experiment` runs the Monte Carlo in chunks of runs and yields partial results (the
app streams them), :func:`run_experiment` returns the final :class:`Results`.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from navlab import memory
from navlab.errors import NavlabError
from navlab.filters.base import Filter, get_filter_class, make_filter
from navlab.linalg import Array, diag, quad
from navlab.metrics import NEES_BOUND, divergence_bound, timed_from
from navlab.noise import OUTLIERS, SCHEDULES, make_outliers, make_schedule
from navlab.params import MAX_EPOCHS, SEED_MAX
from navlab.scenarios.base import Scenario, ScenarioData, concat_runs, get_scenario_class

MAX_RUNS = 20000  # a full run (per-epoch arrays of every run)
MAX_SUMMARY_RUNS = 10_000_000  # a summary run (per-run statistics only)


def _freeze(d: Mapping[str, Any] | None, name: str) -> dict[str, Any]:
    """A JSON copy of parameter group ``name`` (numpy numbers as Python numbers)."""
    if not isinstance(d or {}, Mapping):
        raise NavlabError(f"'{name}' must be a JSON object")

    def item(v: Any) -> Any:
        if isinstance(v, np.generic):
            return v.item()
        raise TypeError(f"{type(v).__name__} {v!r} is not one")

    try:
        return json.loads(json.dumps(dict(d or {}), sort_keys=True, default=item))
    except (TypeError, ValueError) as exc:  # e.g. a key that is not a string
        raise NavlabError(f"'{name}' must hold JSON values (numbers, strings, lists): {exc}") from None


def _whole(v: Any) -> Any:
    """A whole number given as 5.0 or a numpy integer → 5; anything else as it is (plan judges it)."""
    number = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)
    return int(v) if number and abs(v) < 2**63 and int(v) == v else v


@dataclass(frozen=True)
class ExperimentSpec:
    """Everything that defines a run; JSON round-trips; equal specs give identical numbers.

    Attributes
    ----------
    scenario : registry key of the scenario.
    filters : registry keys of the filters, in display order.
    runs, seed : Monte Carlo size and base seed (run r draws the same numbers whatever the chunk it
        is simulated in: navlab.scenarios.base.run_streams).
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
        f = self.filters
        if isinstance(f, str):
            f = [s.strip() for s in f.split(",") if s.strip()]
        if not isinstance(f, (list, tuple)) or not all(isinstance(s, str) for s in f):
            raise NavlabError('\'filters\' must be a list of filter keys, e.g. ["kf", "chi2-kf"]')
        object.__setattr__(self, "filters", tuple(f))
        for name, eg, what in (
            ("scenario", "cv2d", "scenarios"),
            ("noise_schedule", "constant", "schedules"),
            ("outliers", "mixture", "outliers"),
        ):
            if not isinstance(getattr(self, name), str):
                raise NavlabError(
                    f"'{name}' must be a key such as \"{eg}\" (python -m navlab list {what}), "
                    f"got {getattr(self, name)!r}"
                )
        for name in ("runs", "seed", "epochs"):
            object.__setattr__(self, name, _whole(getattr(self, name)))
        for name in ("noise_params", "outlier_params", "scenario_params", "filter_params"):
            object.__setattr__(self, name, _freeze(getattr(self, name), name))
        for k, v in self.filter_params.items():
            if not isinstance(v, Mapping):
                raise NavlabError(f"'filter_params.{k}' must be a JSON object of parameters")

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
        for name in ("noise_params", "outlier_params", "scenario_params", "filter_params"):
            if name in d and not isinstance(d[name], Mapping):  # null too (the constructor takes None)
                raise NavlabError(f"'{name}' must be a JSON object")
        return cls(**d)

    @classmethod
    def from_json(cls, text: str | bytes) -> ExperimentSpec:
        from navlab.io import parse_json

        return cls.from_dict(parse_json(text, "the configuration"))

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


# --------------------------------------------------------------------------- parameters

#: The parameter groups of an experiment, by the short kind the app's widget keys use.
KINDS = {"sc": "scenario_params", "ns": "noise_params", "ol": "outlier_params", "fp": "filter_params"}


def presets(scenario: type[Scenario], kind: str, owner: str) -> dict[str, Any]:
    """The scenario's own defaults for outlier model or filter ``owner`` (``kind`` "ol" / "fp"),
    over the class's defaults (e.g. cv2d's isolated-outlier preset, smartLoc's per-channel χ²).
    """
    table = {"ol": scenario.outlier_defaults, "fp": scenario.filter_defaults}.get(kind, {})
    return dict(table.get(owner, {}))


@dataclass(frozen=True)
class ParamGroup:
    """The parameters of one part of an experiment, resolved in one place.

    A value is the first of: the spec's setting (``values``), the scenario's preset
    (``presets``), the class's default (its ``Params`` dataclass).
    """

    kind: str  # "sc" scenario, "ns" noise schedule, "ol" outlier model, "fp" filter
    owner: str  # its registry key
    cls: type  # the registered class (cls.Params holds the defaults)
    presets: dict[str, Any]
    values: dict[str, Any]

    @property
    def Params(self) -> type:
        return self.cls.Params

    def defaults(self) -> dict[str, Any]:
        """Every parameter's value before the spec: the scenario's preset, else the class's."""
        return {f.name: self.presets.get(f.name, f.default) for f in dataclasses.fields(self.Params)}

    def settings(self) -> dict[str, Any]:
        """What the object is built from (over its class's defaults): presets, then the spec."""
        return {**self.presets, **self.values}


def scenario_group(spec: ExperimentSpec) -> ParamGroup:
    """The scenario's parameters: ``scenario_params``, with ``epochs`` over them."""
    sp = dict(spec.scenario_params)
    if spec.epochs is not None:
        sp["epochs"] = spec.epochs
    return ParamGroup("sc", spec.scenario, get_scenario_class(spec.scenario), {}, sp)


def schedule_group(spec: ExperimentSpec) -> ParamGroup:
    """The noise schedule's parameters: ``noise_params``."""
    cls = SCHEDULES.lookup(spec.noise_schedule)
    return ParamGroup("ns", spec.noise_schedule, cls, {}, dict(spec.noise_params))


def outlier_group(spec: ExperimentSpec) -> ParamGroup:
    """The outlier model's parameters: the scenario's preset, then the ``contamination`` and
    ``outlier_scale`` shortcuts, then ``outlier_params``. NavlabError for an unknown model or a
    shortcut the model does not have.
    """
    if spec.outliers not in OUTLIERS:
        raise NavlabError(f"unknown outlier model '{spec.outliers}'; known: {', '.join(OUTLIERS)}")
    cls = OUTLIERS[spec.outliers]
    fields = {f.name for f in dataclasses.fields(cls.Params)}
    op: dict[str, Any] = {}
    for name, value in (("contamination", spec.contamination), ("scale", spec.outlier_scale)):
        if value is not None:
            if name not in fields:
                raise NavlabError(
                    f"outlier model '{spec.outliers}' has no {name}; "
                    f"use --outliers mixture for a contamination ratio"
                )
            op[name] = value
    op.update(spec.outlier_params)
    scen = get_scenario_class(spec.scenario)
    return ParamGroup("ol", spec.outliers, cls, presets(scen, "ol", spec.outliers), op)


def filter_group(spec: ExperimentSpec, key: str) -> ParamGroup:
    """Filter ``key``'s parameters: the scenario's preset, then ``filter_params[key]``."""
    scen = get_scenario_class(spec.scenario)
    cls = get_filter_class(key)
    return ParamGroup("fp", key, cls, presets(scen, "fp", key), dict(spec.filter_params.get(key, {})))


def param_groups(spec: ExperimentSpec) -> list[ParamGroup]:
    """Every parameter group of ``spec``: scenario, noise schedule, outlier model, each filter."""
    groups = [scenario_group(spec), schedule_group(spec), outlier_group(spec)]
    return groups + [filter_group(spec, k) for k in spec.filters]


def as_plan(spec: ExperimentSpec | Plan, max_runs: int = MAX_RUNS) -> Plan:
    """``spec`` planned, or the plan given (so a caller that planned passes the plan on)."""
    return spec if isinstance(spec, Plan) else plan(spec, max_runs)


def plan(spec: ExperimentSpec, max_runs: int = MAX_RUNS) -> Plan:
    """Validate every part of ``spec`` before any computation; NavlabError says what to change."""
    if not isinstance(spec, ExperimentSpec):
        raise NavlabError(
            f"an experiment is an ExperimentSpec (ExperimentSpec.from_dict for a dict), "
            f"got {type(spec).__name__}"
        )
    big = isinstance(spec.runs, int) and not isinstance(spec.runs, bool) and spec.runs > MAX_RUNS
    if big and max_runs == MAX_RUNS and spec.runs <= MAX_SUMMARY_RUNS:
        raise NavlabError(
            f"'runs' must be at most {MAX_RUNS} for a run that keeps every epoch; for up to "
            f"{MAX_SUMMARY_RUNS} runs use a summary run (--summary: metrics without the "
            "per-epoch arrays)"
        )
    _check_int("runs", spec.runs, 1, max_runs)
    _check_int("seed", spec.seed, 0, SEED_MAX)
    if spec.epochs is not None:
        get_scenario_class(spec.scenario)  # an unknown scenario is named before its epochs
        _check_int("epochs", spec.epochs, 2, MAX_EPOCHS)
    sc = scenario_group(spec)
    scenario = sc.cls(sc.settings())
    if not spec.filters:
        raise NavlabError("choose at least one filter")
    if len(set(spec.filters)) != len(spec.filters):
        raise NavlabError("each filter may be chosen only once")
    unknown_fp = sorted(set(spec.filter_params) - set(spec.filters))
    if unknown_fp:
        raise NavlabError(f"filter_params names filter(s) not in the run: {', '.join(unknown_fp)}")
    filters = []
    for key in spec.filters:
        fg = filter_group(spec, key)
        if fg.cls.family == "oracle" and not sc.cls.simulated:
            raise NavlabError(
                f"'{key}' needs simulator ground truth; scenario '{spec.scenario}' is real data"
            )
        filters.append(make_filter(key, fg.settings()))
    schedule = make_schedule(spec.noise_schedule, schedule_group(spec).settings())
    outliers = make_outliers(spec.outliers, outlier_group(spec).settings())
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
    diverged_at: Array  # (B,) first epoch the run diverged (navlab.metrics rule), −1 if never
    diverged_why: Array  # (B,) int8: 0 no, 1 non-finite state, 2 error bound, 3 NEES bound

    @property
    def diverged(self) -> Array:
        return self.diverged_at >= 0

    @staticmethod
    def concat(parts: Sequence[FilterRun]) -> FilterRun:
        first = parts[0]
        cat = lambda name: concat_runs([getattr(p, name) for p in parts])  # noqa: E731
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
            stats={k: concat_runs([p.stats[k] for p in parts]) for k in first.stats},
            runtime_s=sum(p.runtime_s for p in parts),
            diverged_at=cat("diverged_at"),
            diverged_why=cat("diverged_why"),
        )


def _stack(arrays: Sequence[Any], shape: tuple[int, ...]) -> Array:
    """The per-epoch arrays stacked and broadcast to (L, *shape) (a read-only view may result).

    The usual case — every epoch's array has the same shape, e.g. a P shared by all runs — is one
    np.stack and one broadcast of the result (one broadcast_to, not one per epoch).
    """
    try:
        st = np.stack(arrays)
    except ValueError:  # shapes differ between epochs (a P that became per-run)
        return np.stack([a if np.shape(a) == shape else np.broadcast_to(a, shape) for a in arrays])
    if st.shape[1:] == shape:
        return st
    st = st.reshape((len(arrays),) + (1,) * (len(shape) + 1 - st.ndim) + st.shape[1:])
    return np.broadcast_to(st, (len(arrays), *shape))


def _all_finite(a: Array) -> Array:
    """``np.isfinite(a).all(axis=-1)`` as one matrix-vector product: 0·a is 0 where a is finite
    and NaN where it is not, and a sum of zeros is 0 (exact; the reduction over a short last axis
    cost 4× more: 5.4 → 1.4 ms for 32 epochs × 10 000 runs × 4 states, equal at 15).
    """
    with np.errstate(invalid="ignore"):
        return np.isfinite((a * 0.0) @ np.ones(a.shape[-1]))


class _Recorder:
    """One filter's per-epoch outputs in preallocated arrays; fields appear on first use.

    The arrays are EPOCH-MAJOR, (K+1, B, …): epoch k's slab is a contiguous copy of what the
    filter returned at epoch k, (B, …). Step outputs are buffered and written a block of epochs
    at a time: one np.stack per field (a contiguous copy; of P only its diagonal) and one batched
    NIS per block instead of a dozen small numpy calls per epoch. The block (≤ 32 epochs) is
    sized so the buffer stays within BLOCK_BYTES. :meth:`result` hands out (B, K+1, …) views of
    these arrays (``swapaxes``, no copy). This layout is the recorder's main speed trick, and it
    stayed because it pays: writing each epoch into run-major (B, K+1, …) arrays is a
    transposing, strided copy of every recorded number (``benchmarks/throughput.py`` prints the
    driver + recorder's share of the whole pipeline). The consumers index the views as before;
    the truth of :func:`navlab.scenarios.base.propagate` has the same layout, so the estimation
    errors need no transposing copy either. The other trick: the NEES of a P per run is one call
    per epoch on each P, never a stacked copy of them (:meth:`_nees`; ``benchmarks/tricks.py
    --trick recorder-nees``).
    """

    def __init__(self, f: Filter, data: ScenarioData) -> None:
        B, K1, n, m = data.B, data.K + 1, data.x0.shape[1], data.z.shape[2]
        self.f = f
        self.B, self.K1 = B, K1

        def every_epoch(*shape):  # written at every epoch k ≥ 1 by _flush: no fill, epoch 0 NaN
            a = np.empty((K1, B, *shape))
            a[0] = np.nan
            return a

        self.x, self.P_diag = every_epoch(n), every_epoch(n)
        self.x[0] = data.x0
        self.P_diag[0] = np.diagonal(data.P0)
        self.innov, self.S_diag, self.R_used = every_epoch(m), every_epoch(m), every_epoch(m)
        # a filter may report no R̂ at an epoch
        self.R_hat = np.full((K1, B, m), np.nan) if f.estimates_R else None
        self.nis = every_epoch()
        self.nees = every_epoch() if data.has_truth else np.full((K1, B), np.nan)
        self.weights = np.ones((K1, B, m))
        self.flags = np.zeros((K1, B, m), dtype=np.int8)
        self.stats: dict[str, Array] = {}
        self.runtime = 0.0
        self.diverged_at = np.full(B, -1)
        self.diverged_why = np.zeros(B, dtype=np.int8)
        self.window = np.asarray(data.window, dtype=bool)
        bound = divergence_bound(data) if data.has_truth else None
        self.bound = None
        if bound is not None:
            g = data.groups[bound[0]]
            self.bound = (list(g.idx), g.scale, bound[1] ** 2)
        self._pending: list[tuple[int, Any]] = []
        self.x_true = data.x_true if data.has_truth else None
        self._block = 0  # epochs per block: set from the first step's size (see put)

    BLOCK_BYTES = 48 * 2**20  # what the buffered steps of one filter may hold

    def put(self, k: int, out: Any) -> None:
        if not self._block:  # a block of epochs whose step outputs take at most BLOCK_BYTES
            arrays = [out.x, out.P, out.innov, out.S, out.R_used, out.R_hat, out.weights, out.flags]
            size = sum(np.asarray(a).nbytes for a in (*arrays, *out.stats.values()) if a is not None)
            self._block = int(np.clip(self.BLOCK_BYTES // max(size, 1), 1, 32))
        self._pending.append((k, out))
        if len(self._pending) >= self._block:
            self._flush()

    @staticmethod
    def _put_field(dest: Array, ks: Any, vals: list[Any], diagonal: bool = False) -> None:
        """Write per-epoch values (None: keep the default) into dest[k] for k in ks; with
        ``diagonal`` the values are matrices whose diagonal is written.
        """
        if all(v is not None for v in vals):
            shape = (*dest.shape[1:], *dest.shape[-1:]) if diagonal else dest.shape[1:]
            st = _stack(vals, shape)
            dest[ks] = np.diagonal(st, axis1=-2, axis2=-1) if diagonal else st
            return
        for k, v in zip(range(dest.shape[0])[ks], vals, strict=True):
            if v is not None:
                dest[k] = diag(v) if diagonal else v

    @staticmethod
    def _nees(dx: Array, Ps: list[Array]) -> Array:
        """NEES (L, B) of the errors dx (L, B, n) with the epochs' P, (n, n) or (B, n, n): one call
        on a stacked view while P is shared by the runs, else one call per epoch on each P as the
        filter returned it (a stacked copy of every run's P cost more than the NEES itself).
        """
        if all(P.ndim == 2 for P in Ps):
            return quad(dx, _stack(Ps, (*dx.shape[1:], dx.shape[-1])))
        return np.stack([quad(d, P) for d, P in zip(dx, Ps, strict=True)])

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
        x = np.stack([o.x for o in outs])  # (L, B, n)
        Ps = [o.P for o in outs]  # not stacked: a copy of every run's P would cost more than the NEES
        Pd = _stack([diag(P) for P in Ps], (B, n))  # (L, B, n)
        shared = B > 1 and Pd.strides[1] == 0  # one P for every run (the KF family)
        self.x[ks] = x
        self.P_diag[ks] = Pd
        innov = np.stack([o.innov for o in outs])  # (L, B, m)
        self.innov[ks] = innov
        S = _stack([o.S for o in outs], (B, m, m))
        self.S_diag[ks] = np.diagonal(S, axis1=-2, axis2=-1)
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
                self.stats[name] = np.full((self.K1, B, *v.shape[1:]), np.nan)
            self._put_field(self.stats[name], ks, vals)
        no_nis = [j for j, o in enumerate(outs) if "nis" not in o.stats]
        if len(no_nis) == len(outs):
            self.nis[ks] = quad(innov, S)
        elif no_nis:
            self.nis[[items[j][0] for j in no_nis]] = quad(innov[no_nis], S[no_nis])
        finite_P = _all_finite(Pd[:, :1] if shared else Pd)  # (L, 1 or B)
        why = np.where(_all_finite(x) & finite_P, 0, 1)  # (L, B)
        if self.x_true is not None:
            dx = x - self.x_true[:, ks].swapaxes(0, 1)  # (L, B, n)
            nees = self._nees(dx, Ps)
            self.nees[ks] = nees
            win = self.window[ks][:, None]  # the error and NEES bounds apply inside the analysis window
            with np.errstate(over="ignore", invalid="ignore"):  # a run-away's error is inf
                if self.bound is not None:
                    idx, scale, b2 = self.bound
                    err2 = dx[..., idx[0]] ** 2
                    for i in idx[1:]:
                        err2 += dx[..., i] ** 2
                    why[(why == 0) & win & (err2 * scale**2 > b2)] = 2
                why[(why == 0) & win & (nees > NEES_BOUND)] = 3
        bad = (why != 0).any(axis=0) & (self.diverged_at < 0)
        if bad.any():
            first = np.argmax(why[:, bad] != 0, axis=0)
            self.diverged_at[bad] = np.asarray([k for k, _ in items])[first]
            self.diverged_why[bad] = why[first, bad]

    def result(self) -> FilterRun:
        """Every field as (B, K+1, …) views of the epoch-major arrays."""
        self._flush()
        f = self.f
        runs_first = lambda a: None if a is None else a.swapaxes(0, 1)  # noqa: E731
        return FilterRun(
            key=f.key,
            label=f.label,
            x=runs_first(self.x),
            P_diag=runs_first(self.P_diag),
            innov=runs_first(self.innov),
            S_diag=runs_first(self.S_diag),
            nis=runs_first(self.nis),
            nees=runs_first(self.nees),
            R_used=runs_first(self.R_used),
            R_hat=runs_first(self.R_hat),
            weights=runs_first(self.weights),
            flags=runs_first(self.flags),
            stats={k: runs_first(v) for k, v in self.stats.items()},
            runtime_s=self.runtime,
            diverged_at=self.diverged_at,
            diverged_why=self.diverged_why,
        )


def run_filters(
    data: ScenarioData,
    filters: Sequence[Filter],
    on_epoch: Callable[[int, int], None] | None = None,
) -> dict[str, FilterRun]:
    """Drive every filter through the same batch with ONE loop over epochs.

    At each epoch k = 1 … K every filter predicts (k−1 → k) and updates with the same z_k. Each
    filter's wall time is summed over the epochs :func:`timed_from` names.
    """
    model = data.model
    i = k = 0
    try:
        states = []
        for i, f in enumerate(filters):  # noqa: B007 - i names the failing filter
            states.append(f.init(model, data.x0, data.P0))
        recs = [_Recorder(f, data) for f in filters]
        K = data.K
        first_timed = timed_from(K)
        # no blanket np.errstate here: a filter handles its own expected edge cases locally, so a
        # NaN or an overflow a filter produces unexpectedly warns (and fails the tests, which turn
        # navlab's RuntimeWarnings into errors); a run that blows up is caught by the recorder's
        # divergence rule
        for k in range(1, K + 1):
            zk = data.z[:, k]
            side = data.side(k)
            for i, f in enumerate(filters):
                rec = recs[i]
                t0 = time.perf_counter()
                st = f.predict(model, states[i], k)
                states[i], out = f.update(model, st, k, zk, side)
                if k >= first_timed:
                    rec.runtime += time.perf_counter() - t0
                rec.put(k, out)
            if on_epoch is not None:
                on_epoch(k, K)
    except Exception as exc:
        _plugin_failed(filters[i], k, exc)
        raise
    return {f.key: r.result() for f, r in zip(filters, recs, strict=True)}


def _plugin_failed(f: Filter, k: int, exc: Exception) -> None:
    """A plugin filter's error (its author's to fix) as a NavlabError naming it; navlab's own
    filters' errors stay internal errors.
    """
    from navlab.filters.base import FILTERS

    dist = FILTERS.plugin_sources.get(f.key)
    if dist is None or isinstance(exc, NavlabError):
        return
    where = "in init" if k == 0 else f"at epoch {k}"
    raise NavlabError(
        f"filter '{f.key}' (a plugin, from {dist}) failed {where}: {type(exc).__name__}: {exc}; "
        f"check it with: python -m navlab check-filter {f.key}"
    ) from exc


@dataclass(eq=False)
class Results:
    """The outcome of an experiment (possibly partial while a run streams)."""

    spec: ExperimentSpec
    data: ScenarioData
    runs: dict[str, FilterRun]
    complete: bool = True
    elapsed_s: float = 0.0
    last: Chunk | None = None  # the chunk that completed these results (streaming)

    @property
    def done_runs(self) -> int:
        return self.data.B

    def metrics(self):
        """Tidy metric table (pandas DataFrame): filter, metric, value, unit, ci_lo, ci_hi, …
        (see navlab.metrics.summarize).
        """
        from navlab.metrics import summarize

        return summarize(self)

    def to_xarray(self):
        """The result cube as an ``xarray.Dataset``: filter × run × epoch × channel (× state).

        Truth and data: ``x_true`` (run, epoch, state), ``z``, ``R_true``, ``outlier`` (run, epoch,
        channel), ``R_schedule`` (epoch, channel). Per filter: ``x``, ``P_diag`` (filter, run,
        epoch, state); ``innov``, ``S_diag``, ``R_used`` (diagonals), ``R_hat`` (the filter's R̂
        diagonal, NaN for a filter that does not estimate R), ``weights``, ``flags`` (codes of
        ALGORITHMS.md §0.3) (filter, run, epoch, channel); ``nis``, ``nees`` (filter, run, epoch);
        ``diverged_at`` (filter, run; −1: never). Coordinates: time ``t`` (s), channel units,
        filter labels. Attributes: the experiment's spec (JSON, ``ExperimentSpec.from_dict``
        reads it back) and navlab's version. :func:`save_results` writes it, :func:`load_results`
        reads it back.
        """
        import xarray as xr

        from navlab import __version__

        d = self.data
        keys = list(self.runs)
        runs = [self.runs[k] for k in keys]
        B, K1, m = d.B, d.K + 1, d.z.shape[2]

        def per_filter(name: str, shape: tuple[int, ...], dtype=np.float64) -> np.ndarray:
            out = np.full((len(keys), *shape), np.nan if dtype == np.float64 else 0, dtype=dtype)
            for i, fr in enumerate(runs):
                a = getattr(fr, name)
                if a is not None:
                    out[i] = np.broadcast_to(a, shape)
            return out

        fre, ch, stt = ("filter", "run", "epoch"), ("run", "epoch", "channel"), ("run", "epoch", "state")
        n = d.x_true.shape[2]
        data_vars = {
            "x_true": (stt, np.asarray(d.x_true, dtype=np.float64), {"long_name": "true state"}),
            "z": (ch, np.asarray(d.z, dtype=np.float64), {"long_name": "measurement (NaN: missing)"}),
            "R_true": (ch, np.asarray(d.R_true, dtype=np.float64), {"long_name": "variance drawn"}),
            "outlier": (ch, np.asarray(d.outlier_mask, dtype=np.int8), {"long_name": "contaminated (1)"}),
            "R_schedule": (("epoch", "channel"), np.asarray(d.R_schedule, dtype=np.float64)),
            "x": ((*fre, "state"), per_filter("x", (B, K1, n)), {"long_name": "posterior mean"}),
            "P_diag": ((*fre, "state"), per_filter("P_diag", (B, K1, n)), {"long_name": "diag of P"}),
            "innov": ((*fre, "channel"), per_filter("innov", (B, K1, m))),
            "S_diag": ((*fre, "channel"), per_filter("S_diag", (B, K1, m))),
            "R_used": (
                (*fre, "channel"),
                per_filter("R_used", (B, K1, m)),
                {"long_name": "diag of R in the gain"},
            ),
            "R_hat": ((*fre, "channel"), per_filter("R_hat", (B, K1, m)), {"long_name": "diag of R̂"}),
            "weights": ((*fre, "channel"), per_filter("weights", (B, K1, m))),
            "flags": (
                (*fre, "channel"),
                per_filter("flags", (B, K1, m), np.int8),
                {"long_name": "§0.3 codes"},
            ),
            "nis": (fre, per_filter("nis", (B, K1))),
            "nees": (fre, per_filter("nees", (B, K1))),
            "diverged_at": (("filter", "run"), per_filter("diverged_at", (B,), np.int32)),
        }
        coords = {
            "filter": np.array(keys, dtype=str),
            "filter_label": ("filter", np.array([fr.label for fr in runs], dtype=str)),
            "run": np.asarray(d.runs, dtype=np.int32),
            "epoch": np.arange(K1, dtype=np.int32),
            "t": ("epoch", np.asarray(d.t, dtype=np.float64), {"units": "s"}),
            "channel": np.array(d.channel_names, dtype=str),
            "channel_unit": ("channel", np.array(d.channel_units, dtype=str)),
            "state": np.array(d.state_names, dtype=str),
        }
        attrs = {
            "title": f"navlab results: {self.spec.scenario}, {B} runs",
            "navlab_version": __version__,
            "spec": self.spec.to_json(),
            "scenario": self.spec.scenario,
            "complete": int(self.complete),
        }
        return xr.Dataset(data_vars, coords, attrs)


# --------------------------------------------------------------------------- the one driver

ChunkPolicy = Callable[[int, int], int]  # (runs done, total) -> size of the next chunk


def fixed_chunks(size: int | None) -> ChunkPolicy:
    """Chunks of ``size`` runs (None: all at once)."""
    return lambda done, total: total - done if not size else int(size)


@dataclass(eq=False)
class Chunk:
    """One chunk of Monte Carlo runs: its data and every filter's output over it."""

    data: ScenarioData
    runs: dict[str, FilterRun]
    elapsed_s: float  # simulation + filtering of this chunk


@functools.lru_cache(maxsize=64)
def _dims(scenario_json: str, scenario: str) -> tuple[int, int, int]:
    """(n, m, K) of a scenario configuration, from a one-run probe (cheap: a short run of a
    simulated scenario; a real recording is read once and cached by its loader).
    """
    from navlab.noise import make_outliers, make_schedule

    cls = get_scenario_class(scenario)
    params = json.loads(scenario_json)
    K = params.get("epochs")
    short = cls.simulated and isinstance(K, int) and K > 3
    try:
        sc = cls({**params, "epochs": 3} if short else params)
        data = sc.simulate(make_schedule("constant"), make_outliers("none"), [0], 0)
    except NavlabError:
        if not short:
            raise
        short = False
        data = cls(params).simulate(make_schedule("constant"), make_outliers("none"), [0], 0)
    return int(data.x0.shape[1]), int(data.z.shape[2]), int(K if short else data.K)


def run_size(p: Plan) -> memory.Size:
    """The dimensions that decide the memory of plan ``p``."""
    sp = {f.name: getattr(p.scenario.params, f.name) for f in dataclasses.fields(p.scenario.params)}
    n, m, K = _dims(json.dumps(sp, sort_keys=True, default=list), p.spec.scenario)
    return memory.Size(p.spec.runs, K, n, m, len(p.filters))


def iter_chunks(
    p: Plan,
    policy: ChunkPolicy | None = None,
    start: int = 0,
    on_epoch: Callable[[float], None] | None = None,
) -> Iterator[Chunk]:
    """THE Monte Carlo driver: simulate runs [done, done + n) and drive every filter over them
    (:func:`run_filters`), chunk after chunk, until ``p.spec.runs`` runs are done.

    ``policy(done, total)`` sizes the next chunk (default: all at once); ``on_epoch(runs_done)``
    reports progress within a chunk (fractional runs). Chunking never changes a draw: run r
    draws from its own seed whatever the chunk, and no kernel sizes a run's work by the other
    runs of its batch. The last bits may still differ: BLAS picks its kernel by a product's size,
    so a matrix product over the run axis can round a run's row differently in a batch of another
    size (OpenBLAS 0.3.31 on an AMD EPYC: a few units in the last place); a filter that keeps one
    P for every run while it can (the χ²-KF until a run's gate rejects, the oracle while the
    runs' true R are equal) takes a P per run from an epoch that depends on the batch, and the
    shared and per-run gains round differently; a filter's discrete decisions can amplify that
    (NNMFUKF: 2e-5 relative between 6 runs in one chunk and two of 3).
    The reproductions compute fixed blocks, whose numbers do not depend on the worker count.
    """
    policy = policy or fixed_chunks(None)
    total, done = p.spec.runs, start
    while done < total:
        n = max(1, min(total - done, int(policy(done, total))))
        t0 = time.perf_counter()
        data = p.scenario.simulate(p.schedule, p.outliers, list(range(done, done + n)), p.spec.seed)
        tick = None
        if on_epoch is not None:
            tick = lambda k, K, d=done, b=n: on_epoch(d + b * k / K)  # noqa: E731
        out = run_filters(data, p.filters, tick)
        done += n
        yield Chunk(data, out, time.perf_counter() - t0)


def iter_experiment(
    spec: ExperimentSpec | Plan,
    chunk_runs: int | None = None,
    *,
    policy: ChunkPolicy | None = None,
    start: Results | None = None,
    on_epoch: Callable[[float], None] | None = None,
    budget: int | str | None = None,
) -> Iterator[Results]:
    """Run the Monte Carlo in chunks (``chunk_runs`` each, or as ``policy`` says) and yield the
    accumulated :class:`Results` after each chunk; resumable from partial results ``start``.

    Refused before any computation (NavlabError) when the run would not fit the memory budget
    (:mod:`navlab.memory`). ``spec`` may be its :class:`Plan` (a caller that planned passes it on).
    """
    p = as_plan(spec)
    spec = p.spec
    size = run_size(p)
    alt = size.summary(summary_chunk(size, budget), False)
    memory.check(size, size.full(), budget, as_summary=alt)
    acc = start
    elapsed = 0.0 if start is None else start.elapsed_s
    done0 = 0 if start is None else start.done_runs
    for ch in iter_chunks(p, policy or fixed_chunks(chunk_runs), done0, on_epoch):
        elapsed += ch.elapsed_s
        if acc is None:
            data, runs = ch.data, ch.runs
        else:
            data = ScenarioData.concat([acc.data, ch.data])
            runs = {k: FilterRun.concat([acc.runs[k], ch.runs[k]]) for k in ch.runs}
        acc = Results(spec, data, runs, spec.runs <= data.B, elapsed, ch)
        yield acc


def run_experiment(
    spec: ExperimentSpec,
    on_progress: Callable[[int, int], None] | None = None,
    chunk_runs: int | None = None,
    budget: int | str | None = None,
    on_epoch: Callable[[float], None] | None = None,
) -> Results:
    """Run ``spec`` to completion; ``on_progress(done_runs, total_runs)`` after each chunk,
    ``on_epoch(runs done, fractional)`` after every epoch of a chunk.
    """
    res = None
    for res in iter_experiment(spec, chunk_runs, budget=budget, on_epoch=on_epoch):
        if on_progress is not None:
            on_progress(res.done_runs, spec.runs)
    assert res is not None
    return res


# --------------------------------------------------------------------------- summary runs


class FilterInfo(NamedTuple):
    """A filter of a summary run (no per-epoch arrays)."""

    key: str
    label: str


@dataclass(eq=False)
class DataInfo:
    """What the metrics need of a summary run's data: its configuration and size, no run arrays."""

    scenario: str
    t: Array
    model: Any
    groups: dict[str, Any]
    window: Array
    has_truth: bool
    extras: dict[str, Any]
    divergence_bound: float | None
    B: int
    K: int
    n: int
    m: int
    any_outliers: bool


@dataclass(eq=False)
class SummaryResults:
    """The outcome of a summary run: per-run statistics of every filter, no per-epoch arrays.

    :func:`navlab.metrics.summarize` works on it as on :class:`Results` (the consistency bands'
    in-band share, plain-function scenario metrics and — when ``keep_epochs`` was off — the
    mean of the per-epoch RMSE need per-epoch arrays and are left out).
    """

    spec: ExperimentSpec
    data: DataInfo
    stats: dict[str, Any]  # key -> navlab.metrics.RunStats
    runs: dict[str, FilterInfo]
    elapsed_s: float = 0.0
    complete: bool = True

    @property
    def done_runs(self) -> int:
        return self.data.B

    def metrics(self):
        from navlab.metrics import summarize

        return summarize(self)


def summary_chunk(size: memory.Size, budget: int | str | None = None) -> int:
    """Runs per chunk of a summary run: the most whose full arrays take at most 64 MB and a
    quarter of the budget (at most 5000: beyond, numpy's batched kernels gain nothing). A chunk's
    arrays while it computes and is recorded take about twice their estimate (measured: 1e6 runs
    of kf + huber-kf on cv2d with 256 MB chunks peaked at 982 MB RSS, the interpreter alone 340 MB).
    """
    limit = min(64 * 2**20, memory.budget_bytes(budget) / 4)
    per_run = memory.Size(1, size.epochs, size.n, size.m, size.filters).full()
    return int(max(1, min(5000, size.runs, limit // max(per_run, 1))))


def run_summary(
    spec: ExperimentSpec,
    on_progress: Callable[[int, int], None] | None = None,
    chunk_runs: int | None = None,
    keep_epochs: bool | None = None,
    budget: int | str | None = None,
) -> SummaryResults:
    """Run ``spec`` keeping only per-run statistics (up to :data:`MAX_SUMMARY_RUNS` runs).

    The runs are computed in chunks (``chunk_runs``, default sized to the memory budget); each
    chunk's per-epoch arrays are reduced to the metrics' per-run sufficient statistics and
    dropped. ``keep_epochs`` keeps the per-epoch squared errors too (for the mean of the
    per-epoch RMSE and quantile metrics; default: when they take at most a quarter of the
    budget). The numbers equal a full run's (the same runs, the same statistics).
    """
    from navlab.metrics import RunStats, run_stats

    p = plan(spec, max_runs=MAX_SUMMARY_RUNS)
    size = run_size(p)
    chunk = int(chunk_runs) if chunk_runs else summary_chunk(size, budget)
    if keep_epochs is None:  # float32 squared errors of up to 8 groups per filter
        sq_bytes = size.runs * (size.epochs + 1) * size.filters * 8 * 4
        keep_epochs = sq_bytes <= min(256 * 2**20, memory.budget_bytes(budget) / 8)
    memory.check(size, size.summary(chunk, keep_epochs), budget, summary=True)
    stats: dict[str, RunStats] = {}  # every run's statistics, written in place chunk by chunk
    info: DataInfo | None = None
    outliers = False
    elapsed = 0.0
    at = 0
    for ch in iter_chunks(p, fixed_chunks(chunk)):
        if info is None:  # what the metrics need of the data: from the first chunk, then dropped
            info = DataInfo(
                scenario=ch.data.scenario,
                t=ch.data.t,
                model=ch.data.model,
                groups=ch.data.groups,
                window=ch.data.window,
                has_truth=ch.data.has_truth,
                extras={k: v for k, v in ch.data.extras.items() if k in ("metrics", "notes", "findings")},
                divergence_bound=ch.data.divergence_bound,
                B=spec.runs,
                K=ch.data.K,
                n=int(ch.data.x0.shape[1]),
                m=int(ch.data.z.shape[2]),
                any_outliers=False,
            )
        outliers = outliers or bool(ch.data.outlier_mask.any())
        for key, fr in ch.runs.items():
            part = run_stats(ch.data, fr).compact(keep_epochs)
            if key not in stats:
                stats[key] = RunStats.allocate(part, spec.runs)
            stats[key].put(at, part)
        at += ch.data.B
        elapsed += ch.elapsed_s
        if on_progress is not None:
            on_progress(int(ch.data.runs[-1]) + 1, spec.runs)
    assert info is not None
    assert at == spec.runs
    info = dataclasses.replace(info, any_outliers=outliers)
    labels = {f.key: FilterInfo(f.key, f.label) for f in p.filters}
    return SummaryResults(spec, info, stats, labels, elapsed)


# --------------------------------------------------------------------------- results on disk
# netCDF3 through xarray's scipy engine: scipy is already a dependency, so a saved cube needs no C
# library (netCDF4/HDF5) to write or read; netCDF3 holds every variable here (float64, int32,
# int8, text) and its files open in any netCDF reader (xarray, MATLAB ncread, ncdump).
NETCDF_ENGINE = "scipy"


def save_results(res: Results, path: str | os.PathLike) -> None:
    """Write ``res.to_xarray()`` to ``path`` (netCDF3: see :data:`NETCDF_ENGINE`)."""
    ds = res.to_xarray()
    try:
        ds.to_netcdf(path, engine=NETCDF_ENGINE)
    except OSError as exc:
        raise NavlabError(f"cannot write {path}: {exc.strerror or exc}") from None


def load_results(path: str | os.PathLike):
    """The ``xarray.Dataset`` a :func:`save_results` (``navlab run --save-results``) wrote, loaded
    into memory; ``ExperimentSpec.from_dict(json.loads(ds.attrs["spec"]))`` is its experiment.
    """
    import xarray as xr

    try:
        with xr.open_dataset(path, engine=NETCDF_ENGINE) as ds:
            out = ds.load()
    except FileNotFoundError:
        raise NavlabError(f"no results file {path}") from None
    except (OSError, ValueError, TypeError) as exc:
        raise NavlabError(f"{path} is not a netCDF results file navlab wrote: {exc}") from None
    if "spec" not in out.attrs or "navlab_version" not in out.attrs:
        raise NavlabError(f"{path} is a netCDF file but not navlab results (no spec attribute)")
    from navlab.io import parse_json

    try:  # JSON only: a spec of another navlab version may have other keys
        if not isinstance(parse_json(str(out.attrs["spec"]), "its spec attribute"), dict):
            raise NavlabError("its spec attribute is not a JSON object")
    except NavlabError as exc:
        raise NavlabError(f"{path}: a damaged results file ({exc}); write it again") from None
    return out
