"""The filter interface, the system-model interface and the filter registry.

One shared time loop (:func:`navlab.experiment.run_filters`) drives every filter. A filter is a
stateless object holding its frozen hyper-parameters; everything that changes per run lives in a
state object (a NamedTuple with at least ``x`` (B, n) and ``P`` ((n, n) or (B, n, n))) that the
filter returns from :meth:`Filter.init`, :meth:`Filter.predict` and :meth:`Filter.update`.

Epoch convention (every scenario): k = 0 is the initial epoch (truth x_0, estimate x̂_0, P_0, no
measurement); for k = 1 … K the loop calls ``predict`` (transition k−1 → k) then ``update`` with z_k.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple, Protocol

import numpy as np

from navlab import params as P_
from navlab.linalg import Array, mv, predict_cov
from navlab.registry import Registry


class Model(Protocol):
    """What a filter may ask of a scenario's (nominal) system model at epoch k.

    Matrices may be shared (n, n) or per run (B, n, n); filters must broadcast.
    """

    n: int
    m: int
    R0: Array  # (m, m) nominal measurement-noise covariance the filters assume
    linear: bool

    def F(self, k: int) -> Array: ...  # transition k-1 -> k (Jacobian of f for nonlinear models)
    def Q(self, k: int) -> Array: ...  # process noise over k-1 -> k
    def f(self, x: Array, k: int) -> Array: ...  # (B, n) -> (B, n)
    def H(self, x: Array, k: int) -> Array: ...  # Jacobian of h at x: (m, n) or (B, m, n)
    def h(self, x: Array, k: int) -> Array: ...  # (B, n) -> (B, m)


@dataclass(frozen=True, eq=False)
class LinearModel:
    """Linear Gaussian model. ``F``, ``Q``, ``H`` are constant (2-D) or per epoch (3-D, index k)."""

    F_: Array
    Q_: Array
    H_: Array
    R0: Array
    linear: bool = True

    @property
    def n(self) -> int:
        return int(self.F_.shape[-1])

    @property
    def m(self) -> int:
        return int(self.H_.shape[-2])

    def F(self, k: int) -> Array:
        return self.F_ if self.F_.ndim == 2 else self.F_[k]

    def Q(self, k: int) -> Array:
        return self.Q_ if self.Q_.ndim == 2 else self.Q_[k]

    def f(self, x: Array, k: int) -> Array:
        return mv(self.F(k), x)

    def H(self, x: Array | None, k: int) -> Array:
        return self.H_ if self.H_.ndim == 2 else self.H_[k]

    def h(self, x: Array, k: int) -> Array:
        return mv(self.H(x, k), x)


@dataclass(frozen=True)
class SideInfo:
    """What the simulator knows at epoch k (only the oracle filter reads it).

    R_true : (B, m) variance actually used to draw v_k (mixture component included).
    bias : (B, m) known additive outlier mean (0 if none).
    outlier : (B, m) bool, channel contaminated by the outlier model at k.
    Q_extra : (n, n) process-noise anomaly, or None.
    """

    R_true: Array
    bias: Array
    outlier: Array
    Q_extra: Array | None = None


@dataclass
class StepOut:
    """Per-step report of one filter (ALGORITHMS.md §0.2 rule 5). Shared arrays may be unbatched.

    Attributes
    ----------
    x, P : posterior mean (B, n) and covariance ((n, n) or (B, n, n)).
    innov : innovation ν = z − h(x⁻), (B, m) (0 on missing channels).
    S : innovation covariance the filter used, (m, m) or (B, m, m).
    R_used : effective R in the gain, (m, m) or (B, m, m).
    R_hat : the filter's adaptive estimate of R, or None if it does not estimate R.
    weights : (B, m) per-channel weights, 1 = untouched (None: all ones).
    flags : (B, m) per-channel codes of §0.3 (None: all zeros).
    stats : extra per-run diagnostics, arrays (B,) or (B, m) (NIS, fading factors, λ, …).
    """

    x: Array
    P: Array
    innov: Array
    S: Array
    R_used: Array
    R_hat: Array | None = None
    weights: Array | None = None
    flags: Array | None = None
    stats: dict[str, Array] = field(default_factory=dict)


class KFState(NamedTuple):
    """The minimal per-run state: mean (B, n) and covariance ((n, n) or (B, n, n))."""

    x: Array
    P: Array


# Per-channel flag codes (ALGORITHMS.md §0.3)
ACCEPTED, DOWNWEIGHTED, REJECTED, REJECTED_AUX, REPLACED, EPOCH_ANOMALY, R_HAT_AT_BAND, NUMERICAL_FIX = (
    0,
    1,
    2,
    3,
    4,
    5,
    6,
    9,
)
FLAG_NAMES = {
    0: "accepted",
    1: "down-weighted",
    2: "rejected",
    3: "rejected (aux. detector)",
    4: "replaced by prediction",
    5: "epoch anomaly",
    6: "R̂ held at its band",
    9: "numerical fix",
}


@dataclass(frozen=True)
class Teaching:
    """What the Learn page teaches about a filter (navlab/learn.py reads it from the class).

    idea : one paragraph in plain words.
    equations : the key equations, LaTeX, one ``st.latex`` call each (from ALGORITHMS.md).
    caveat : what the tiny step-through example cannot show for this filter ("" if nothing).
    """

    idea: str = ""
    equations: tuple[str, ...] = ()
    caveat: str = ""


@dataclass(frozen=True)
class KFLimit:
    """Parameter values under which a filter reduces to the standard KF (§1.1).

    The contract tests (tests/contract) run the filter with ``params`` beside ``kf`` on data with
    the nominal R and no outliers and require the same estimates.

    params : the filter's parameters in the limit (e.g. a Huber threshold γ → ∞ as 1e12).
    linear_only : the reduction holds on linear models only (the unscented transform of a linear
        map is exact; of a nonlinear one it is not the EKF's linearisation).
    why : one line on why this is the limit.
    """

    params: dict[str, Any]
    linear_only: bool = False
    why: str = ""


def band_param(bound: str) -> Any:
    """A parameter of the band an adaptive filter keeps R̂ in, [r_min, r_max] × R0 (ALGORITHMS.md §4.1
    step 4, §3.1): ``bound`` "r_min" or "r_max".
    """
    what = "R̂ kept within [r_min, r_max] × R0 (R̂ relative to the nominal R0: on real data, the receiver's σ²)"
    if bound == "r_min":
        return P_.param(0.01, lo=1e-6, hi=1.0, help=f"lower bound of the band: {what}")
    return P_.param(1e4, lo=1.0, hi=1e8, help=f"upper bound of the band: {what}")


def flag_fix(flags: Array, fixed: Array, *, overwrite: bool = True) -> Array:
    """Mark numerical fixes (flag 9, §0.3) in the per-channel ``flags`` (B, m), in place.

    ``fixed`` is () or (B,) (the whole run, e.g. a singular S that needed jitter) or (B, m) (the
    channels concerned, e.g. an R̂ variance moved by the eigenvalue clamp). ``overwrite``: the fix
    replaces whatever code the channel had; otherwise only still-accepted channels (code 0) get 9,
    so a down-weighting or rejection stays visible. Returns ``flags``.
    """
    fixed = np.asarray(fixed, dtype=bool)
    if fixed.any():
        if fixed.ndim < 2:  # per run
            fixed = np.broadcast_to(fixed, flags.shape[:1])[:, None]
        where = np.broadcast_to(fixed, flags.shape)
        if not overwrite:
            where = where & (flags == ACCEPTED)
        flags[where] = NUMERICAL_FIX
    return flags


class Filter:
    """Base class: subclass, set the class attributes, implement init/predict/update, register.

    Class attributes
    ----------------
    key : registry key, kebab-case (``"huber-kf"``).
    label : display name.
    family : "baseline", "robust", "adaptive", "robust-adaptive", "nonlinear", "oracle".
    paper : short citation of the paper it implements ("" for textbook filters).
    spec_section : the section of ALGORITHMS.md it follows.
    reconstruction : True where the original could not be retrieved (shown in the app).
    estimates_R : True if it reports an R̂.
    predictive_density : True if its ``StepOut.stats["logpdf"]`` (B, m) holds the log predictive
        density of each measurement before the update (NaN where missing): the metric ``nlpd``.
    teaching : :class:`Teaching` — idea, key equations, caveat (the Learn page).
    kf_limit : :class:`KFLimit` — parameters under which it is the KF (None: it never is).
    linear_only : True if it needs a linear model (uses F, H; ignores f, h).
    Params : frozen dataclass of hyper-parameters declared with :func:`navlab.params.param`.
    """

    key: ClassVar[str] = ""
    label: ClassVar[str] = ""
    family: ClassVar[str] = "baseline"
    paper: ClassVar[str] = ""
    spec_section: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    reconstruction: ClassVar[bool] = False
    estimates_R: ClassVar[bool] = False
    predictive_density: ClassVar[bool] = False
    linear_only: ClassVar[bool] = False
    Params: ClassVar[type] = P_.NoParams
    teaching: ClassVar[Teaching] = Teaching()
    kf_limit: ClassVar[KFLimit | None] = None

    def __init__(self, params: Any = None, **kwargs: Any) -> None:
        if params is None or isinstance(params, dict):
            params = P_.build(self.Params, {**(params or {}), **kwargs}, f"filter '{self.key}'")
        self.params = params

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.params})"

    # The three hooks -----------------------------------------------------------------------
    def init(self, model: Model, x0: Array, P0: Array) -> Any:
        """Initial state from x̂_0 (B, n) and P_0 ((n, n) or (B, n, n))."""
        return KFState(np.array(x0, dtype=float), np.array(P0, dtype=float))

    def predict(self, model: Model, state: Any, k: int) -> Any:
        """Time update k−1 → k (default: the KF/EKF prediction)."""
        return state._replace(x=model.f(state.x, k), P=predict_cov(model.F(k), state.P, model.Q(k)))

    def update(self, model: Model, state: Any, k: int, z: Array, side: SideInfo) -> tuple[Any, StepOut]:
        """Measurement update with z_k (B, m) (NaN = channel unavailable)."""
        raise NotImplementedError(f"{type(self).__name__} defines no update(model, state, k, z, side)")


def _check_filter(cls: type[Filter]) -> None:
    if not dataclasses.is_dataclass(cls.Params):
        raise TypeError(f"{cls.__name__}.Params must be a dataclass")


#: Every filter, by key; the modules of :mod:`navlab.filters` register theirs with :func:`register`.
FILTERS: Registry[type[Filter]] = Registry(
    "filter", package="navlab.filters", check=_check_filter, plugins="navlab.filters"
)

#: Class decorator adding a filter to :data:`FILTERS` under ``cls.key`` (kebab-case).
register = FILTERS.register


def registry() -> dict[str, type[Filter]]:
    """All registered filters, by key (a copy of :data:`FILTERS`)."""
    return dict(FILTERS)


def is_oracle(key: str) -> bool:
    """Whether ``key`` is a registered filter of the oracle family (told the truth: shown as the
    genie reference, never ranked); False for a key no filter is registered under.
    """
    cls = FILTERS.get(key)
    return cls is not None and cls.family == "oracle"


def get_filter_class(key: str) -> type[Filter]:
    """The filter class registered as ``key``; NavlabError naming the known keys otherwise."""
    return FILTERS.lookup(key)


def make_filter(key: str, params: dict[str, Any] | None = None) -> Filter:
    """Instantiate a registered filter with validated parameters."""
    return FILTERS.make(key, params)
