"""Teaching material for the Learn page: each filter's idea and equations, and a step-through.

Nothing here imports streamlit. Each filter's idea, key equations (LaTeX, one string per
``st.latex`` call) and caveat are on its class (:class:`~navlab.filters.base.Teaching`, written
from ../shared/ALGORITHMS.md); :func:`filter_info` reads them. :func:`step_through` runs a
registered filter's real ``init`` / ``predict`` / ``update`` with B = 1 on a tiny constant-velocity
example (:class:`TinySpec`), with an outlier the user places, and returns a tidy per-step table:
innovation, S, NIS against the χ² threshold, weights, flags, stats, R_used and R̂ per epoch and
channel. A filter that cannot run on the tiny linear example (it needs an INS, a trained network,
side data …) is reported as not applicable with the reason, never as an exception.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from navlab.errors import NavlabError
from navlab.filters.base import (
    FLAG_NAMES,
    Filter,
    LinearModel,
    SideInfo,
    Teaching,
    get_filter_class,
    registry,
)
from navlab.linalg import Array, chi2_ppf, quad

# ------------------------------------------------------------------------------------ teaching
# Each filter's idea, key equations and caveat live on its class (``Filter.teaching``, written from
# ALGORITHMS.md beside the code that implements them); a variant class that does not write its
# own (``nnmfukf-guarded``) shows the filter it builds on.


def _documented(cls: type[Filter]) -> type[Filter] | None:
    """The class whose teaching ``cls`` shows: itself, or the nearest base that has some."""
    for c in cls.__mro__:
        t = c.__dict__.get("teaching")
        if isinstance(t, Teaching) and (t.idea or t.equations):
            return c
    return None


def _cls(key: str) -> type[Filter] | None:
    return registry().get(key)


def base_key(key: str) -> str | None:
    """The registered filter whose teaching ``key`` shows (``nnmfukf-guarded`` → ``nnmfukf``)."""
    cls = _cls(key)
    doc = _documented(cls) if cls is not None else None
    return doc.key if doc is not None else None


def equations(key: str) -> list[str]:
    """The LaTeX lines for filter ``key``, or its base filter's for a variant ([] if none)."""
    cls = _cls(key)
    doc = _documented(cls) if cls is not None else None
    return list(doc.teaching.equations) if doc is not None else []


def caveat(key: str) -> str:
    """What the tiny example cannot show for ``key`` (or for the filter it is a variant of)."""
    cls = _cls(key)
    doc = _documented(cls) if cls is not None else None
    return doc.teaching.caveat if doc is not None else ""


def idea(cls: type[Filter]) -> str:
    """One paragraph about the filter: its own ``teaching.idea``, else its summary and docstring
    (plus the base filter's idea for a variant such as ``nnmfukf-guarded``).
    """
    doc = _documented(cls)
    if doc is cls:
        return cls.teaching.idea
    text = (cls.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
    parts = [s for s in (cls.summary, text) if s]
    text = " ".join(parts) if parts else "No description yet."
    if doc is not None and doc.teaching.idea:
        text += f" It is a variant of `{doc.key}`: {doc.teaching.idea}"
    return text


# ------------------------------------------------------------------------------- tiny example
@dataclass(frozen=True)
class TinySpec:
    """The tiny constant-velocity example of the step-through.

    dims : 1 (state [p, v], one position measurement) or 2 (state [x, y, v_x, v_y], x and y
        measured; the measured states come first, so H = [I 0]).
    epochs : number of updates K.
    outlier_epoch : epoch (1 … K) with an outlier added; 0 = none.
    outlier_size : the outlier in units of the measurement σ (can be negative).
    outlier_channel : "first" or "all" channels get the outlier.
    noise_scale : the true measurement σ is noise_scale·√r (1 = the filters' R is right).
    seed : seed of the measurement and process noise.
    dt, q, r : sampling interval (s), acceleration-noise variance (m²/s⁴), nominal R (m²).
    p0_pos, p0_vel : initial variances (m², m²/s²).
    alpha : false-alarm probability of the χ² threshold drawn against the NIS.
    """

    dims: int = 1
    epochs: int = 8
    outlier_epoch: int = 5
    outlier_size: float = 10.0
    outlier_channel: str = "first"
    noise_scale: float = 1.0
    seed: int = 0
    dt: float = 1.0
    q: float = 0.01
    r: float = 1.0
    p0_pos: float = 4.0
    p0_vel: float = 1.0
    alpha: float = 0.01

    def validate(self) -> TinySpec:
        """Return self, or raise NavlabError saying which value to change."""
        if self.dims not in (1, 2):
            raise NavlabError(f"dims must be 1 or 2, got {self.dims!r}")
        if not isinstance(self.epochs, int) or not 1 <= self.epochs <= 200:
            raise NavlabError(f"epochs must be a whole number in [1, 200], got {self.epochs!r}")
        if not isinstance(self.outlier_epoch, int) or not 0 <= self.outlier_epoch <= self.epochs:
            raise NavlabError(
                f"outlier_epoch must be 0 (none) or an epoch in 1 … {self.epochs}, got {self.outlier_epoch!r}"
            )
        if self.outlier_channel not in ("first", "all"):
            raise NavlabError("outlier_channel must be 'first' or 'all'")
        for name in ("outlier_size", "noise_scale", "dt", "q", "r", "p0_pos", "p0_vel", "alpha"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise NavlabError(f"{name} must be a finite number, got {v!r}")
        for name in ("dt", "r", "p0_pos", "p0_vel", "noise_scale"):
            if getattr(self, name) <= 0:
                raise NavlabError(f"{name} must be positive, got {getattr(self, name)!r}")
        if self.q < 0:
            raise NavlabError(f"q must be ≥ 0, got {self.q!r}")
        if not 0 < self.alpha < 0.5:
            raise NavlabError(f"alpha must be in (0, 0.5), got {self.alpha!r}")
        if abs(self.outlier_size) > 1e6:
            raise NavlabError("outlier_size must be within ±1e6 σ")
        return self


@dataclass(frozen=True, eq=False)
class TinyData:
    """The simulated tiny example (B = 1). Arrays indexed by epoch 0 … K (z[0] is NaN)."""

    spec: TinySpec
    model: LinearModel
    x_true: Array  # (K+1, n)
    z: Array  # (K+1, m)
    R_true: Array  # (K+1, m) variance the noise was drawn with
    bias: Array  # (K+1, m) outlier added (known to the oracle)
    outlier: Array  # (K+1, m) bool
    x0: Array  # (n,) initial estimate
    P0: Array  # (n, n)
    state_names: tuple[str, ...]
    channel_names: tuple[str, ...]

    @property
    def K(self) -> int:
        return int(self.z.shape[0] - 1)

    def side(self, k: int) -> SideInfo:
        return SideInfo(R_true=self.R_true[None, k], bias=self.bias[None, k], outlier=self.outlier[None, k])


def tiny_model(spec: TinySpec) -> tuple[LinearModel, tuple[str, ...], tuple[str, ...]]:
    """The constant-velocity model: (model, state names, channel names). Measured states first."""
    d, dt = spec.dims, spec.dt
    F = np.block([[np.eye(d), dt * np.eye(d)], [np.zeros((d, d)), np.eye(d)]])
    G = np.vstack([0.5 * dt**2 * np.eye(d), dt * np.eye(d)])
    Q = spec.q * G @ G.T
    H = np.hstack([np.eye(d), np.zeros((d, d))])
    R0 = spec.r * np.eye(d)
    if d == 1:
        names, chans = ("p", "v"), ("p",)
    else:
        names, chans = ("x", "y", "v_x", "v_y"), ("x", "y")
    return LinearModel(F, Q, H, R0), names, chans


def simulate_tiny(spec: TinySpec) -> TinyData:
    """Truth and measurements of the tiny example (deterministic in ``spec.seed``)."""
    spec.validate()
    model, names, chans = tiny_model(spec)
    d, K = spec.dims, spec.epochs
    n, m = 2 * d, d
    rng = np.random.default_rng([int(spec.seed), 20261123])
    P0 = np.diag([spec.p0_pos] * d + [spec.p0_vel] * d)
    x = np.zeros((K + 1, n))
    x[0, d:] = 1.0  # moving at 1 m/s (each axis)
    x[0] += rng.standard_normal(n) * np.sqrt(np.diag(P0))
    G = np.vstack([0.5 * spec.dt**2 * np.eye(d), spec.dt * np.eye(d)])
    for k in range(1, K + 1):
        x[k] = model.F_ @ x[k - 1] + G @ (rng.standard_normal(d) * math.sqrt(spec.q))
    x0 = np.zeros(n)
    x0[d:] = 1.0  # the filters' initial estimate: the mean the truth was drawn around
    var = np.full((K + 1, m), spec.r * spec.noise_scale**2)
    noise = rng.standard_normal((K + 1, m)) * np.sqrt(var)
    bias = np.zeros((K + 1, m))
    outlier = np.zeros((K + 1, m), dtype=bool)
    j = spec.outlier_epoch
    if j > 0 and spec.outlier_size != 0:
        ch = slice(0, 1) if spec.outlier_channel == "first" else slice(None)
        bias[j, ch] = spec.outlier_size * np.sqrt(var[j, ch])
        outlier[j, ch] = True
    z = x @ model.H_.T + noise + bias
    z[0] = np.nan
    return TinyData(spec, model, x, z, var, bias, outlier, x0, P0, names, chans)


# -------------------------------------------------------------------------------- step-through
@dataclass(eq=False)
class StepThrough:
    """The outcome of :func:`step_through` for one filter.

    applicable : False if the filter cannot run on the tiny example (``reason`` says why).
    steps : tidy table, one row per (epoch, channel) — see :data:`STEP_COLUMNS` (+ ``stat:<name>``
        columns for the filter's scalar and per-channel stats).
    states : tidy table, one row per (epoch, state): truth, prior, posterior and their variances.
    extra_stats : {epoch: {name: array}} stats of other shapes (e.g. per-iteration VB traces).
    threshold : χ²_{1−α}(m) the NIS is compared with.
    """

    key: str
    label: str
    applicable: bool
    reason: str
    data: TinyData | None
    steps: pd.DataFrame
    states: pd.DataFrame
    extra_stats: dict[int, dict[str, Array]]
    threshold: float

    @property
    def epochs(self) -> int:
        return 0 if self.data is None else self.data.K

    def epoch_table(self) -> pd.DataFrame:
        """One row per epoch: NIS (filter's S, nominal S₀), threshold, outlier, flag, weight."""
        if self.steps.empty:
            return pd.DataFrame(columns=["epoch", "nis", "nis_threshold", "nis_exceeds"])
        g = self.steps.groupby("epoch", sort=True)
        out = g.agg(
            nis=("nis", "first"),
            nis_threshold=("nis_threshold", "first"),
            nis_exceeds=("nis_exceeds", "first"),
            nis_nominal=("nis_nominal", "first"),
            nis_nominal_exceeds=("nis_nominal_exceeds", "first"),
            outlier=("outlier", "any"),
            min_weight=("weight", "min"),
            max_flag=("flag", "max"),
        ).reset_index()
        return out


STEP_COLUMNS = [
    "epoch",
    "t",
    "channel",
    "z",
    "z_pred",
    "truth",
    "innov",
    "S",
    "innov_norm",
    "nis",
    "nis_threshold",
    "nis_exceeds",
    "dof",
    "nis_nominal",
    "nis_nominal_exceeds",
    "R_true",
    "R_used",
    "R_hat",
    "weight",
    "flag",
    "flag_name",
    "outlier",
]
STATE_COLUMNS = ["epoch", "state", "truth", "prior", "posterior", "P_prior", "P_post", "error"]


def _mat(a: Any, m: int) -> Array | None:
    """An (m, m) matrix from an (m, m) or (1, m, m) array."""
    if a is None:
        return None
    a = np.asarray(a, dtype=float)
    if a.ndim == 3:
        a = a[0]
    if a.shape != (m, m):
        raise NavlabError(f"expected an {m}×{m} matrix, got shape {a.shape}")
    return a


def _vec(a: Any, m: int, default: float) -> Array:
    """A length-m vector from (1, m) / (m,) / None."""
    if a is None:
        return np.full(m, default)
    a = np.asarray(a, dtype=float)
    if a.ndim == 2:
        a = a[0]
    return np.broadcast_to(a, (m,)).astype(float)


def _not_applicable(cls: type[Filter], reason: str, data: TinyData | None) -> StepThrough:
    return StepThrough(
        cls.key,
        cls.label,
        False,
        reason,
        data,
        pd.DataFrame(columns=STEP_COLUMNS),
        pd.DataFrame(columns=STATE_COLUMNS),
        {},
        float("nan"),
    )


def _precheck(cls: type[Filter]) -> str | None:
    """A reason why ``cls`` cannot run on the tiny linear example, known without running it."""
    needs = getattr(cls, "needs", None) or getattr(cls, "requires", None)
    if needs:
        return f"it needs {needs}, which the tiny constant-velocity example does not provide"
    return None


def step_through(key: str, spec: TinySpec | None = None, params: dict[str, Any] | None = None) -> StepThrough:
    """Run filter ``key`` on the tiny example with B = 1 and record every step.

    Uses the filter's own ``init`` / ``predict`` / ``update``. Any failure of the filter on this
    example (an exception, a numerical warning, a non-finite result) makes it "not applicable"
    with the reason; an unknown key or bad spec/params raise NavlabError.
    """
    spec = (spec or TinySpec()).validate()
    cls = get_filter_class(key)
    flt = cls(params or {})  # bad parameters are the user's to fix: NavlabError propagates
    data = simulate_tiny(spec)
    pre = _precheck(cls)
    if pre:
        return _not_applicable(cls, pre, data)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            rows, srows, extra = _run(flt, data)
    except NavlabError as exc:
        return _not_applicable(cls, f"not applicable to the tiny linear example: {exc}", data)
    except (FloatingPointError, RuntimeWarning) as exc:
        return _not_applicable(
            cls, f"numerical problem on the tiny example ({type(exc).__name__}: {exc})", data
        )
    except Exception as exc:  # any filter failure becomes a readable reason
        return _not_applicable(
            cls,
            f"cannot run on the tiny linear example ({type(exc).__name__}: {exc}); it may need a "
            "scenario-specific model (an INS, a trained network, pseudoranges)",
            data,
        )
    steps = pd.DataFrame(rows)
    states = pd.DataFrame(srows, columns=STATE_COLUMNS)
    if not np.isfinite(states["posterior"].to_numpy(dtype=float)).all():
        return _not_applicable(cls, "diverged on the tiny example (non-finite estimate)", data)
    thr = float(chi2_ppf(1.0 - spec.alpha, data.model.m))
    return StepThrough(cls.key, cls.label, True, "", data, steps, states, extra, thr)


def _state_rows(data: TinyData, k: int, x_prior, x_post, P_prior, P_post) -> list[dict[str, Any]]:
    """One row a state at epoch ``k``: truth, prior and posterior estimate and variance, error."""
    xt = data.x_true
    return [
        {
            "epoch": k,
            "state": data.state_names[i],
            "truth": xt[k, i],
            "prior": x_prior[i],
            "posterior": x_post[i],
            "P_prior": P_prior[i, i],
            "P_post": P_post[i, i],
            "error": x_post[i] - xt[k, i],
        }
        for i in range(data.model.n)
    ]


def _initial_state_rows(data: TinyData) -> list[dict[str, Any]]:
    """The state rows of epoch 0: the prior x0, P0 as the posterior (no prior before it)."""
    xt = data.x_true
    return [
        {
            "epoch": 0,
            "state": data.state_names[i],
            "truth": xt[0, i],
            "prior": np.nan,
            "posterior": data.x0[i],
            "P_prior": np.nan,
            "P_post": data.P0[i, i],
            "error": data.x0[i] - xt[0, i],
        }
        for i in range(data.model.n)
    ]


def _split_stats(stats: dict, m: int) -> tuple[dict[str, float], dict[str, Array], dict[str, Array]]:
    """A filter's stats of one epoch (B = 1): scalars and per-channel (m,) arrays, prefixed
    ``stat:``, and anything else as it is: (scalars, per channel, other).
    """
    scal: dict[str, float] = {}
    perch: dict[str, Array] = {}
    other: dict[str, Array] = {}
    for name, v in stats.items():
        a = np.asarray(v, dtype=float)
        if a.ndim >= 1 and a.shape[0] == 1:
            a = a[0]
        if a.ndim == 0:
            scal[f"stat:{name}"] = float(a)
        elif a.shape == (m,):
            perch[f"stat:{name}"] = a
        else:
            other[name] = a
    return scal, perch, other


def _nis_values(model, stats: dict, k: int, innov, S, x_prior, P_prior) -> tuple[float, float]:
    """The NIS (the filter's own if it reports one; ``nis`` is taken out of ``stats``) and the NIS
    with the nominal S₀ = H P⁻ Hᵀ + R₀ (a robust filter's own S is already inflated, which hides
    the outlier from its own NIS).
    """
    if "nis" in stats:
        nis = float(np.asarray(stats.pop("nis"), dtype=float).reshape(-1)[0])
    else:
        nis = float(quad(innov[None, :], S)[0])
    Hk = np.asarray(model.H(x_prior[None, :], k), dtype=float)
    S0 = Hk @ P_prior @ Hk.T + model.R0
    return nis, float(quad(innov[None, :], S0)[0])


def _channel_rows(
    data: TinyData, k: int, out, innov: Array, S: Array, nis: tuple[float, float], stats: tuple
) -> list[dict[str, Any]]:
    """One row a channel at epoch ``k``: measurement, prediction, truth, innovation, NIS against
    the χ² threshold, R (true, used, R̂), weight and flag, and the filter's stats.
    """
    model, spec = data.model, data.spec
    m = model.m
    nis, nis_nom = nis
    R_used = _mat(out.R_used, m)
    R_hat = _mat(out.R_hat, m) if out.R_hat is not None else None
    weights = _vec(out.weights, m, 1.0)
    flags = _vec(out.flags, m, 0.0).astype(int)
    dof = int(np.isfinite(data.z[k]).sum())
    thr = float(chi2_ppf(1.0 - spec.alpha, max(dof, 1)))
    scal, perch = stats
    rows = []
    for i in range(m):
        row = {
            "epoch": k,
            "t": k * spec.dt,
            "channel": data.channel_names[i],
            "z": data.z[k, i],
            "z_pred": data.z[k, i] - innov[i],
            "truth": float(model.H_[i] @ data.x_true[k]),
            "innov": innov[i],
            "S": S[i, i],
            "innov_norm": innov[i] / math.sqrt(S[i, i]) if S[i, i] > 0 else np.nan,
            "nis": nis,
            "nis_threshold": thr,
            "nis_exceeds": bool(nis > thr),
            "dof": dof,
            "nis_nominal": nis_nom,
            "nis_nominal_exceeds": bool(nis_nom > thr),
            "R_true": data.R_true[k, i],
            "R_used": R_used[i, i],
            "R_hat": np.nan if R_hat is None else R_hat[i, i],
            "weight": weights[i],
            "flag": int(flags[i]),
            "flag_name": FLAG_NAMES.get(int(flags[i]), str(int(flags[i]))),
            "outlier": bool(data.outlier[k, i]),
        }
        row.update(scal)
        row.update({name: float(v[i]) for name, v in perch.items()})
        rows.append(row)
    return rows


def _run(flt: Filter, data: TinyData):
    """Run ``flt`` over the tiny example (B = 1): (channel rows, state rows, other stats per epoch)."""
    model = data.model
    n, m = model.n, model.m
    state = flt.init(model, data.x0[None, :], data.P0.copy())
    rows: list[dict[str, Any]] = []
    srows = _initial_state_rows(data)
    extra: dict[int, dict[str, Array]] = {}
    for k in range(1, data.K + 1):
        st = flt.predict(model, state, k)
        x_prior = np.asarray(st.x, dtype=float).reshape(-1, n)[0].copy()
        P_prior = np.asarray(st.P, dtype=float)
        P_prior = (P_prior[0] if P_prior.ndim == 3 else P_prior).copy()
        state, out = flt.update(model, st, k, data.z[None, k], data.side(k))
        x_post = np.asarray(out.x, dtype=float).reshape(-1, n)[0]
        P_post = _mat(out.P, n)
        innov = _vec(out.innov, m, np.nan)
        S = _mat(out.S, m)
        stats = dict(out.stats or {})
        nis = _nis_values(model, stats, k, innov, S, x_prior, P_prior)
        scal, perch, other = _split_stats(stats, m)
        if other:
            extra.setdefault(k, {}).update(other)
        rows += _channel_rows(data, k, out, innov, S, nis, (scal, perch))
        srows += _state_rows(data, k, x_prior, x_post, P_prior, P_post)
    return rows, srows, extra


def applicability(spec: TinySpec | None = None) -> dict[str, StepThrough]:
    """Run the step-through for every registered filter (each with its default parameters)."""
    return {key: step_through(key, spec) for key in sorted(registry())}


def filter_info(cls: type[Filter]) -> dict[str, Any]:
    """What the Learn page shows about a filter class (plain data, no streamlit)."""
    from navlab.params import describe

    return {
        "key": cls.key,
        "label": cls.label or cls.key,
        "family": cls.family,
        "paper": cls.paper or "textbook",
        "spec_section": cls.spec_section,
        "summary": cls.summary,
        "reconstruction": bool(cls.reconstruction),
        "idea": idea(cls),
        "equations": equations(cls.key),
        "equations_of": base_key(cls.key),
        "caveat": caveat(cls.key),
        "params": describe(cls.Params) if dataclasses.is_dataclass(cls.Params) else [],
    }
