"""The contract every registered filter keeps, as a library: ``navlab check-filter`` and the tests.

One implementation of the checks, two callers: ``tests/contract/`` parametrises them over every
registered filter × every compatible scenario (a new filter, built in or a plugin, is checked with
no test to write), and ``navlab check-filter NAME`` (:func:`check_filter`) runs them on one filter
and prints what fails in words.

The data: each scenario simulated once per process (:data:`RUNS` runs, a few epochs: the contracts
are per step) in three variants — ``normal`` (the scenario's default outliers), ``clean`` (no
outliers: the KF limits) and ``gappy`` (normal plus missing channels and a missing epoch). Every
filter run happens with RuntimeWarnings as errors and numpy's floating-point errors as warnings,
so a NaN or overflow inside a filter fails the contract.

A check returns nothing when the contract holds, raises :class:`ContractError` (a message saying
what differs, where and by how much) when it does not, and :class:`ContractSkipped` when it does not
apply (a real recording absent from this machine, a model the filter refuses, no reference).
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec, plan
from navlab.filters import SideInfo, StepOut, make_filter, registry
from navlab.filters.base import FLAG_NAMES, KFLimit
from navlab.scenarios import ScenarioData, scenario_registry

RUNS = 3
SEED = 7
EPOCHS = {"drive0708": 6, "gps-ins-rtk": 10}  # default: 10 (few epochs: the contracts are per step)
EPOCHS_DEFAULT = 10

# (filter, scenario) cases whose reference check takes seconds: the skew-t reference computes
# scipy's truncated-normal moments per channel and VB iteration, on smartloc-berlin's 20 satellites
# 11–35 s on a 2-core machine (tests/contract/conftest.py marks them slow).
SLOW_REFERENCES = {("skew-t-kf", "smartloc-berlin")}


class ContractError(NavlabError):
    """A filter breaks a contract; the message says which, where and by how much."""


class ContractSkipped(Exception):  # noqa: N818 - an outcome, not an error
    """The check does not apply to this case (the message says why)."""


def _require(ok: Any, message: str) -> None:
    if not bool(ok):
        raise ContractError(message)


# -- data and driver ---------------------------------------------------------------------------
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
        raise ContractSkipped(f"scenario {scenario} unavailable: {exc}") from None
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


def cases(filters: Iterable[str] | None = None) -> list[tuple[str, str]]:
    """Every (filter, scenario) pair the contracts run on: registered × compatible."""
    keys = list(registry()) if filters is None else list(filters)
    return [(f, s) for f in keys for s in scenario_registry() if compatible(f, s) is None]


def filter_for(fkey: str, scenario: str, params: dict[str, Any] | None = None):
    """The filter with the scenario's presets (as an experiment builds it) and ``params`` over them."""
    fp = {**scenario_registry()[scenario].filter_defaults.get(fkey, {}), **(params or {})}
    return make_filter(fkey, fp)


@dataclass
class Run:
    """Step outputs (epochs 1 … K) and the states after each update."""

    outs: list[StepOut]
    states: list[Any]


def drive(f, data: Any, runs=slice(None), model=None, z=None, epochs: int | None = None) -> Run:
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
            raise ContractSkipped(f"{f.key} refuses this model: {exc}") from None
        for k in range(1, K + 1):
            try:
                st = f.predict(model, st, k)
                st, out = f.update(model, st, k, z[runs, k], data.side(k, runs))
            except RuntimeWarning as exc:
                raise ContractError(
                    f"numpy warned at epoch k={k} ({exc}): a NaN, overflow or division by zero "
                    "inside the filter"
                ) from None
            outs.append(out)
            states.append(st)
    return Run(outs, states)


@functools.cache
def cached_run(fkey: str, scenario: str, variant: str) -> Run:
    """The filter (scenario presets) over the whole batch of a data variant, run once per process."""
    return drive(filter_for(fkey, scenario), scenario_data(scenario, variant))


def batched_P(P: np.ndarray, B: int) -> np.ndarray:
    return np.broadcast_to(P, (B, *np.shape(P)[-2:]))


def state_sigma(run: Run, B: int) -> np.ndarray:
    """(K, B, n) posterior standard deviations."""
    return np.sqrt(np.abs(np.stack([np.diagonal(batched_P(o.P, B), axis1=-2, axis2=-1) for o in run.outs])))


def _where(err: np.ndarray, tol: float) -> str:
    """Where a (K, B, …) error array is largest and first exceeds ``tol``, in words."""
    k, r = np.unravel_index(int(np.nanargmax(err)), err.shape)[:2]
    first = int(np.argmax((~(err <= tol)).reshape(err.shape[0], -1).any(axis=1))) + 1
    return f"largest at epoch k={k + 1}, run {r}; first above tolerance at k={first}"


def assert_same_estimates(a: Run, b: Run, B: int, rel: float, what: str) -> None:
    """Estimates equal: x to ``rel`` of the posterior σ (plus rel·|x|), P equal to ``rel`` relative."""
    xa, xb = np.stack([o.x for o in a.outs]), np.stack([o.x for o in b.outs])
    sig = state_sigma(b, B)
    err = np.abs(xa - xb) / (sig + np.abs(xb) + 1e-300)
    _require(
        np.all(err <= rel),
        f"{what}: the state estimate x differs by {np.nanmax(err):.2e} of its σ ({_where(err, rel)}; "
        f"tolerance {rel:g})",
    )
    Pa = np.stack([batched_P(o.P, B) for o in a.outs])
    Pb = np.stack([batched_P(o.P, B) for o in b.outs])
    d = np.sqrt(np.abs(np.diagonal(Pb, axis1=-2, axis2=-1)))
    scale = d[..., :, None] * d[..., None, :] + 1e-300
    perr = np.abs(Pa - Pb) / scale
    _require(
        np.all(perr <= rel),
        f"{what}: the covariance P differs by {np.nanmax(perr):.2e} relative ({_where(perr, rel)}; "
        f"tolerance {rel:g})",
    )


# -- the checks --------------------------------------------------------------------------------
def check_finite(fkey: str, scenario: str) -> None:
    """No NaN, overflow or division by zero inside the filter on normal data, with or without
    missing channels (the driver turns every RuntimeWarning into an error), and finite estimates.
    """
    for variant in ("normal", "gappy"):
        for k, o in enumerate(cached_run(fkey, scenario, variant).outs, start=1):
            _require(
                np.isfinite(o.x).all() and np.isfinite(o.P).all(),
                f"non-finite estimate at epoch k={k} on the {variant} data",
            )


def check_shapes(fkey: str, scenario: str) -> None:
    """Every StepOut field has the documented shape and dtype (navlab.filters.base.StepOut)."""
    data = scenario_data(scenario, "gappy")
    B, n, m = RUNS, data.x0.shape[1], data.z.shape[2]
    cls = registry()[fkey]
    for o in cached_run(fkey, scenario, "gappy").outs:
        _require(
            o.x.shape == (B, n) and o.x.dtype == np.float64,
            f"x is {o.x.shape} {o.x.dtype}, not ({B}, {n}) float64",
        )
        P = np.asarray(o.P)
        _require(
            P.shape in ((n, n), (B, n, n)) and P.dtype == np.float64,
            f"P is {P.shape} {P.dtype}, not (n, n) or (B, n, n) float64",
        )
        _require(o.innov.shape == (B, m), f"innov is {o.innov.shape}, not ({B}, {m})")
        _require(np.isfinite(o.innov).all(), "innov is not finite (it must be 0 on missing channels)")
        for name in ("S", "R_used"):
            _require(
                np.shape(getattr(o, name)) in ((m, m), (B, m, m)),
                f"{name} is {np.shape(getattr(o, name))}, not (m, m) or (B, m, m)",
            )
        _require(
            (o.R_hat is not None) == cls.estimates_R,
            f"R_hat is {'set' if o.R_hat is not None else 'None'} "
            f"but the class says estimates_R={cls.estimates_R}",
        )
        if o.R_hat is not None:
            _require(np.shape(o.R_hat) in ((m, m), (B, m, m)), f"R_hat is {np.shape(o.R_hat)}")
        if o.weights is not None:
            w = np.asarray(o.weights)
            _require(
                w.shape == (B, m) and np.isfinite(w).all() and (w >= 0).all(),
                "weights must be finite, ≥ 0, (B, m)",
            )
        if o.flags is not None:
            f = np.asarray(o.flags)
            _require(
                f.shape == (B, m) and np.issubdtype(f.dtype, np.integer),
                f"flags is {f.shape} {f.dtype}, not ({B}, {m}) integer",
            )
            _require(
                set(np.unique(f).tolist()) <= set(FLAG_NAMES),
                f"unknown flag codes {set(np.unique(f).tolist()) - set(FLAG_NAMES)}",
            )
        for name, v in o.stats.items():
            _require(np.shape(v)[:1] == (B,), f"stats[{name!r}] has shape {np.shape(v)}, not (B, …)")
        _require(
            ("logpdf" in o.stats) == cls.predictive_density,
            f"stats['logpdf'] {'present' if 'logpdf' in o.stats else 'absent'} "
            f"but predictive_density={cls.predictive_density}",
        )
        if cls.predictive_density:  # finite where a measurement is, NaN where none is
            lp, ok = np.asarray(o.stats["logpdf"]), np.isfinite(o.innov) & (o.innov != 0)
            _require(
                lp.shape == (B, m) and np.isfinite(lp[ok]).all(),
                "stats['logpdf'] not finite where a measurement is",
            )


def check_deterministic(fkey: str, scenario: str) -> None:
    """Two runs on the same data give bit-identical estimates and flags."""
    data = scenario_data(scenario, "gappy")
    a = cached_run(fkey, scenario, "gappy")
    b = drive(filter_for(fkey, scenario), data)
    for k, (oa, ob) in enumerate(zip(a.outs, b.outs, strict=True), start=1):
        same = np.array_equal(oa.x, ob.x) and np.array_equal(oa.P, ob.P)
        fa = np.zeros(0) if oa.flags is None else oa.flags
        fb = np.zeros(0) if ob.flags is None else ob.flags
        _require(same and np.array_equal(fa, fb), f"a second run on the same data differs at epoch k={k}")


def _run_slice(o: StepOut, r: int) -> StepOut:
    """The StepOut of run r alone (a shared P stays shared)."""
    P = np.asarray(o.P)
    return type(o)(
        x=o.x[r : r + 1],
        P=P[r : r + 1] if P.ndim == 3 else P,
        innov=o.innov[r : r + 1],
        S=o.S,
        R_used=o.R_used,
        flags=None if o.flags is None else np.asarray(o.flags)[r : r + 1],
    )


def check_batched(fkey: str, scenario: str) -> None:
    """Each run alone gives what it gives inside the batch (no run leaks into another)."""
    data = scenario_data(scenario, "gappy")
    batch = cached_run(fkey, scenario, "gappy")
    for r in range(RUNS):
        one = drive(filter_for(fkey, scenario), data, runs=slice(r, r + 1))
        part = Run([_run_slice(o, r) for o in batch.outs], [])
        assert_same_estimates(one, part, 1, 1e-7, f"run {r} alone vs the same run in the batch")
        for k, (oa, ob) in enumerate(zip(one.outs, part.outs, strict=True), start=1):
            if oa.flags is not None:
                _require(np.array_equal(oa.flags, ob.flags), f"run {r}: flags differ at epoch k={k}")


def check_psd(fkey: str, scenario: str) -> None:
    """P stays symmetric and positive semidefinite (with missing channels too)."""
    for k, o in enumerate(cached_run(fkey, scenario, "gappy").outs, start=1):
        P = batched_P(o.P, RUNS)
        scale = np.abs(P).max(axis=(-2, -1), keepdims=True)
        _require(
            np.all(np.abs(P - P.swapaxes(-1, -2)) <= 1e-12 * scale), f"P is not symmetric at epoch k={k}"
        )
        w = np.linalg.eigvalsh(P)
        _require(
            np.all(w.min(axis=-1) >= -1e-9 * np.abs(w).max(axis=-1)),
            f"P is not positive semidefinite at epoch k={k} (smallest eigenvalue {w.min():.3g})",
        )


class DropChannel:
    """``model`` with channel ``i`` removed (h, H, R0 and the per-channel hooks), all else delegated."""

    def __init__(self, model, i: int) -> None:
        self.base = model
        self.keep = np.array([j for j in range(model.m) if j != i])
        self.m = len(self.keep)
        self.n = model.n
        self.R0 = np.asarray(model.R0)[np.ix_(self.keep, self.keep)]
        self.linear = getattr(model, "linear", False)

    def H(self, x, k):
        return np.asarray(self.base.H(x, k))[..., self.keep, :]

    def h(self, x, k):
        return np.asarray(self.base.h(x, k))[..., self.keep]

    def __getattr__(self, name):
        attr = getattr(self.base, name)
        if name == "nn_reference":  # a per-channel hook (NNMFUKF): its channels go too
            return lambda k: np.asarray(attr(k))[..., self.keep]
        if name == "positive_skew":  # a per-channel mask (skew-t KF): its channel goes too
            return np.asarray(attr)[self.keep]
        return attr


@dataclass
class _Dropped:
    """The data of a scenario with channel i removed (what the filter sees through DropChannel)."""

    data: ScenarioData
    keep: list[int]

    def __post_init__(self) -> None:
        self.K, self.x0, self.P0 = self.data.K, self.data.x0, self.data.P0
        self.z = self.data.z[:, :, self.keep]

    def side(self, k, sl=slice(None)):
        s = self.data.side(k, sl)
        return SideInfo(s.R_true[:, self.keep], s.bias[:, self.keep], s.outlier[:, self.keep], s.Q_extra)


def check_nan_channel(fkey: str, scenario: str, outlier: bool = False) -> None:
    """A channel with NaN gets a zero gain column: the posterior equals the update with that
    channel removed from the model (first update from the same initial state) — with ``outlier``
    also when another channel carries a 30σ outlier, so that the robust branches (down-weighting,
    rejection, covariance inflation) run with a channel missing.
    """
    data = scenario_data(scenario, "normal")
    i = 0
    z = data.z.copy()
    if outlier:
        j = data.z.shape[2] - 1
        H = np.asarray(data.model.H(data.x0, 1))
        Hj = H[..., j, :]
        s_j = np.sqrt(np.einsum("...i,ij,...j->...", Hj, np.asarray(data.P0), Hj) + data.model.R0[j, j])
        z[:, 1, j] = z[:, 1, j] + 30.0 * s_j
        data = replace(data, z=z.copy())
    z[:, 1, i] = np.nan
    full = drive(filter_for(fkey, scenario), data, z=z, epochs=1)
    keep = [j for j in range(data.z.shape[2]) if j != i]
    small = drive(
        filter_for(fkey, scenario), _Dropped(data, keep), model=DropChannel(data.model, i), epochs=1
    )
    # with a 30σ outlier the update is ill-conditioned (fading factors at their cap, a vague WLS
    # prior): the two formulations then agree to a few 1e-5 only, round-off amplified
    rel = 1e-4 if outlier else 1e-8
    what = "channel 0 NaN vs channel 0 removed from the model" + (
        " (a 30σ outlier on another)" if outlier else ""
    )
    assert_same_estimates(full, small, RUNS, rel, what)
    _require(np.all(full.outs[0].innov[:, i] == 0.0), "innov must be 0 on a missing channel")


def check_declared_limit(fkey: str, scenario: str) -> None:
    """With the parameters of its declared ``kf_limit`` the filter is the KF (nominal R, no outliers)."""
    lim: KFLimit | None = registry()[fkey].kf_limit
    if lim is None:
        raise ContractSkipped(f"{fkey} declares no kf_limit (parameters under which it is the KF)")
    data = scenario_data(scenario, "clean")
    if lim.linear_only and not getattr(data.model, "linear", False):
        raise ContractSkipped(f"{fkey} reduces to the KF on linear models only ({lim.why})")
    got = drive(filter_for(fkey, scenario, lim.params), data)
    kf = cached_run("kf", scenario, "clean")
    why = f": {lim.why}" if lim.why else ""
    assert_same_estimates(got, kf, RUNS, 1e-6, f"with {lim.params} (its declared KF limit{why}) vs kf")


def check_limit_not_vacuous(fkey: str, scenario: str = "cv2d") -> None:
    """With its default parameters a filter that declares a limit differs from the KF."""
    lim = registry()[fkey].kf_limit
    if lim is None or not lim.params:
        raise ContractSkipped(f"{fkey} declares no kf_limit with parameters")
    kf = cached_run("kf", scenario, "normal")
    run = cached_run(fkey, scenario, "normal")
    dx = max(np.abs(a.x - b.x).max() for a, b in zip(run.outs, kf.outs, strict=True))
    _require(
        dx > 1e-6,
        f"with its default parameters {fkey} gives the KF on {scenario} (max |Δx| {dx:.1e}): "
        "the declared-limit check proves nothing",
    )


def check_reference(fkey: str, scenario: str) -> None:
    """The fast (batched) filter equals its plain one-run reference, run by run."""
    registry()  # plugins first: a plugin's module registers its reference when it is loaded
    from navlab.filters.reference import REFERENCES

    if fkey not in REFERENCES:
        raise ContractSkipped(
            f"{fkey} has no reference: write the filter's plain one-run transcription and register "
            f"it with @navlab.filters.reference.reference({fkey!r}) (see docs: add your own filter); "
            "a filter written as one-run steps (navlab.jit.RunStep) is checked by 'compiled = uncompiled'"
        )
    data = scenario_data(scenario, "normal")
    f = filter_for(fkey, scenario)
    fast = cached_run(fkey, scenario, "normal")
    ref = REFERENCES[fkey]
    for r in range(RUNS):
        sides = [None] + [data.side(k, slice(r, r + 1)) for k in range(1, data.K + 1)]
        sides = [None] + [type(s)(s.R_true[0], s.bias[0], s.outlier[0], s.Q_extra) for s in sides[1:]]
        try:
            tr = ref(data.model, data.x0[r], np.asarray(data.P0), data.z[r], sides, f.params)
        except NotImplementedError as exc:
            raise ContractSkipped(f"the reference of {fkey} does not cover this case: {exc}") from None
        x = np.stack([o.x[r] for o in fast.outs])
        P = np.stack([batched_P(o.P, RUNS)[r] for o in fast.outs])
        sig = np.sqrt(np.abs(np.diagonal(tr.P, axis1=-2, axis2=-1)))
        err = np.abs(x - tr.x) / (sig + 1e-9 * np.abs(tr.x) + 1e-300)
        bad = (err >= 1e-6).any(axis=1)
        _require(
            not bad.any(),
            f"run {r}: the state estimate x differs from the reference by {err.max():.2e} σ "
            f"(first at epoch k={int(np.argmax(bad)) + 1}; tolerance 1e-6)",
        )
        d = np.sqrt(np.abs(np.diagonal(tr.P, axis1=-2, axis2=-1)))
        perr = np.abs(P - tr.P) / (d[:, :, None] * d[:, None, :] + 1e-300)
        _require(perr.max() < 1e-6, f"run {r}: P differs from the reference by {perr.max():.2e} relative")
        if tr.R_hat is not None:
            R = np.stack([np.broadcast_to(o.R_hat, (RUNS, *tr.R_hat.shape[1:]))[r] for o in fast.outs])
            tol = 1e-6 * np.abs(tr.R_hat) + 1e-9 * np.abs(tr.R_hat).max()
            _require(np.all(np.abs(R - tr.R_hat) <= tol), f"run {r}: R̂ differs from the reference")
        if tr.weights is not None:
            w = np.stack([np.ones(data.z.shape[2]) if o.weights is None else o.weights[r] for o in fast.outs])
            _require(
                np.allclose(w, tr.weights, rtol=1e-6, atol=1e-9),
                f"run {r}: weights differ from the reference",
            )
        if tr.flags is not None:
            fl = np.stack([o.flags[r] for o in fast.outs])
            keep = fl != 9  # a numerical fix (the reference never repairs) overrides the code
            _require(np.array_equal(fl[keep], tr.flags[keep]), f"run {r}: flags differ from the reference")


def check_compiled(fkey: str, scenario: str) -> None:
    """The compiled kernels (navlab.jit: a filter's one-run step looped by RunStep, the shared
    linear algebra) give the numbers of the same Python uncompiled, to round-off.
    """
    from navlab import jit

    if not jit.enabled():
        raise ContractSkipped("numba is not available: there is nothing compiled to compare")
    data = scenario_data(scenario, "normal")
    with jit.numpy_paths():
        plain = drive(filter_for(fkey, scenario), data)
    assert_same_estimates(cached_run(fkey, scenario, "normal"), plain, RUNS, 1e-8, "compiled vs uncompiled")


@dataclass(frozen=True)
class Contract:
    """One named check: ``run(fkey, scenario)``; ``per_scenario`` False: run once (on cv2d)."""

    name: str
    run: Callable[[str, str], None]
    per_scenario: bool = True


#: The contract suite, in the order ``navlab check-filter`` reports it.
CONTRACTS: tuple[Contract, ...] = (
    Contract("finite, no numpy warning", check_finite),
    Contract("StepOut shapes and dtypes", check_shapes),
    Contract("deterministic", check_deterministic),
    Contract("batched = run by run", check_batched),
    Contract("P symmetric PSD", check_psd),
    Contract("NaN channel = channel removed", check_nan_channel),
    Contract("NaN channel with an outlier", functools.partial(check_nan_channel, outlier=True)),
    Contract("declared KF limit", check_declared_limit),
    Contract("KF limit not vacuous", check_limit_not_vacuous, per_scenario=False),
    Contract("equals its reference", check_reference),
    Contract("compiled = uncompiled", check_compiled),
)


@dataclass(frozen=True)
class Outcome:
    """One contract on one scenario: status "pass", "fail" or "skip", and the message."""

    contract: str
    scenario: str
    status: str
    message: str = ""


def check_filter(
    fkey: str,
    scenarios: Iterable[str] | None = None,
    on_outcome: Callable[[Outcome], None] | None = None,
) -> list[Outcome]:
    """Run the contract suite on filter ``fkey`` (every compatible scenario, or ``scenarios``).

    Returns one :class:`Outcome` per contract and scenario (``on_outcome`` is called with each as
    it comes). An unknown filter or scenario is a NavlabError naming the known ones.
    """
    from navlab.filters.base import FILTERS
    from navlab.scenarios.base import SCENARIOS

    FILTERS.lookup(fkey)
    if scenarios is None:
        todo = [s for f, s in cases([fkey])]
    else:
        todo = [s for s in scenarios if SCENARIOS.lookup(s) and compatible(fkey, s) is None]
    if not todo:
        raise NavlabError(f"filter '{fkey}' is compatible with none of the scenarios asked for")
    out: list[Outcome] = []
    for c in CONTRACTS:
        for s in todo if c.per_scenario else ["cv2d"]:
            try:
                c.run(fkey, s)
                o = Outcome(c.name, s, "pass")
            except ContractSkipped as exc:
                o = Outcome(c.name, s, "skip", str(exc))
            except ContractError as exc:
                o = Outcome(c.name, s, "fail", str(exc))
            except NavlabError as exc:  # the filter refused its parameters or data: in words
                o = Outcome(c.name, s, "fail", f"{type(exc).__name__}: {exc}")
            except Exception as exc:  # a bug in the filter: a failure of the contract, not of navlab
                o = Outcome(c.name, s, "fail", f"raised {type(exc).__name__}: {exc}")
            out.append(o)
            if on_outcome is not None:
                on_outcome(o)
    return out
