"""Sage–Husa family: classic SHAKF, IRAKF (Ge, Zhang, Tang 2020) and its three comparators.

Every filter here estimates the measurement-noise covariance R from the innovations or the
posterior residuals, and (except the classic SHAKF) protects itself against outliers:

* ``sage-husa`` — classic fading-memory Sage–Husa R estimate (ALGORITHMS.md §4.1).
* ``irakf`` — windowed residual R estimate (RAE, S1 eq. 3) with the prior covariance of eq. 4 on
  suspect epochs, a three-segment IGG/Huber weight function with gain-column zeroing (eq. 7) and
  dual detection by a parallel standard KF (Fig. 1) (§4.2–4.6).
* ``rrae`` — RAE + classical IGG-III equivalent weights (§4.7, RECONSTRUCTION).
* ``rakf`` — Sage–Husa + divergence-triggered P inflation + whitened-innovation Huber clipping
  (§4.8, RECONSTRUCTION).
* ``rsshakf`` — simplified (R-only, diagonal) Sage–Husa + outlier variance inflation (§4.9,
  RECONSTRUCTION).

The weight functions and the RAE estimate are module-level pure functions so that tests (and the
app) can call them on their own.

Implementation note (speed; issue 6). With B runs of tiny matrices numpy's per-call overhead, not
arithmetic, is the cost, so the updates avoid LAPACK and n×n×n products per epoch: U = P⁻Hᵀ and
H P⁻ Hᵀ by indexing when H selects states (:func:`linalg.PHt`), the gain from the closed-form
S⁻¹ for m ≤ 3 (:func:`linalg.kf_gain`, LU when S is ill-conditioned), the Joseph form from U and S
(:func:`linalg.joseph_from_gain`, its exact expansion), and the eigenvalue clamp of R̂ only on the
runs whose eigenvalues are not certainly inside the bounds (:func:`_clamp`). Every result equals
the straightforward formulas up to round-off (tests/unit/test_linear_pinned.py).

References
----------
A. P. Sage, G. W. Husa, "Adaptive filtering with unknown prior statistics", JACC 1969.
Ge B., Zhang H., Tang Z., "Improved robust adaptive Kalman filter with innovation-based outliers
diagnosis", Navigation Positioning and Timing 7(1), 2020, doi:10.19306/j.cnki.2095-8110.2020.01.007.
A. H. Mohamed, K. P. Schwarz, "Adaptive Kalman filtering for INS/GPS", J. Geodesy 73, 1999.
Yang Y., He H., Xu G., "Adaptively robust filtering for kinematic geodetic positioning",
J. Geodesy 75, 2001 (IGG-III equivalent weights).
Bai Y. Q., Han J. H., Qi X. H., "Data processing algorithm of MEMS inclinometer based on improved
Sage-Husa adaptive Kalman filter", Chinese Control Conference 2012 (abstract only).
M. Narasimhappa, S. L. Sabat, J. Nayak, "Fiber-optic gyroscope signal denoising using an adaptive
robust Kalman filter", IEEE Sensors J. 16(10), 2016 (not retrieved).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from navlab.errors import NavlabError
from navlab.filters.base import (
    ACCEPTED,
    DOWNWEIGHTED,
    EPOCH_ANOMALY,
    NUMERICAL_FIX,
    REJECTED,
    REJECTED_AUX,
    Filter,
    Model,
    SideInfo,
    StepOut,
    register,
)
from navlab.linalg import (
    Array,
    PHt,
    batched,
    bcast,
    diag,
    diag_embed,
    eigh_clamp,
    forward_subst,
    joseph_from_gain,
    kf_gain,
    mask_missing,
    mT,
    mv,
    predict_cov,
    solve_sym,
    sym,
)
from navlab.params import param

# ------------------------------------------------------------------------------ pure kernels


def forgetting_weight(k: int, b: float) -> float:
    """Sage–Husa fading-memory weight d_k = (1 − b)/(1 − b^{k+1}), k = 1 at the first update.

    b = 1 is the limit d_k = 1/(k + 1) (plain running average including the prior R0).
    """
    if k < 1:
        raise ValueError("k counts updates from 1")
    if b >= 1.0:
        return 1.0 / (k + 1)
    return (1.0 - b) / (1.0 - b ** (k + 1))


_BOUNDS_CACHE: dict[tuple, tuple[float, float]] = {}


def _bounds(R0: Array) -> tuple[float, float]:
    """:func:`rhat_bounds`, cached per R0 (it is evaluated every epoch)."""
    R0 = np.asarray(R0, dtype=float)
    key = (R0.shape, R0.tobytes())
    if key not in _BOUNDS_CACHE:
        if len(_BOUNDS_CACHE) > 64:
            _BOUNDS_CACHE.clear()
        _BOUNDS_CACHE[key] = rhat_bounds(R0)
    return _BOUNDS_CACHE[key]


def rhat_bounds(R0: Array) -> tuple[float, float]:
    """Eigenvalue clamp [r_min, r_max] = [0.01·min diag R0, 1e4·max diag R0] (§4.1 step 4)."""
    d = np.diag(np.asarray(R0, dtype=float))
    return 0.01 * float(d.min()), 1e4 * float(d.max())


def irakf_weights(
    nu_tilde: Array, k0: float, k1: float, middle: str = "huber", sigma: Array | None = None
) -> tuple[Array, Array]:
    """Three-segment weights of S1 eq. 7 on normalised innovations ν̃ = ν/σ (§4.4).

    Returns ``(w, zone)``: the factor multiplying ν_i (1, k0/|ν̃| in the middle zone, 0 in the
    rejection zone, where IRAKF zeroes the gain column) and the zone code 0/1/2.
    ``middle="literal"`` is the seed's printed ν/c1 with c1 = k1·σ_i in measurement units (weight
    1/(k1 σ_i), dimensionally inconsistent; kept only for comparison; needs ``sigma``).
    """
    a = np.abs(nu_tilde)
    above0, above1 = a > k0, a > k1
    zone = _zone(above0, above1, k0, k1)
    if middle == "literal":
        if sigma is None:
            raise ValueError("middle='literal' needs sigma")
        with np.errstate(divide="ignore"):
            mid = 1.0 / (k1 * sigma)
    elif k0 > 0:  # k0/max(|ν̃|, k0) is k0/|ν̃| in the middle zone and exactly 1 below it (fmax: NaN → 1)
        return np.where(above1, 0.0, k0 / np.fmax(a, k0)), zone
    else:
        mid = k0 / np.where(a > 0, a, 1.0)
    w = np.where(above1, 0.0, np.where(above0, mid, 1.0))
    return w, zone


def _zone(above0: Array, above1: Array, k0: float, k1: float) -> Array:
    """Zone code 0/1/2 (int8) from |ν̃| > k0 and |ν̃| > k1."""
    if k1 >= k0:  # then above1 implies above0: the sum of the two 0/1 bytes
        return above0.view(np.int8) + above1.view(np.int8)
    return np.where(above1, np.int8(2), above0.astype(np.int8))


def igg3_weights(nu_tilde: Array, k0: float, k1: float) -> tuple[Array, Array]:
    """Yang's IGG-III equivalent weights (§4.7 step 3): continuous, 1 → 0 between k0 and k1.

    w = 1 (|ν̃| ≤ k0); (k0/|ν̃|)·((k1 − |ν̃|)/(k1 − k0))² (k0 < |ν̃| ≤ k1); 0 (|ν̃| > k1).
    Returns ``(w, zone)`` with zone 0/1/2.
    """
    a = np.abs(nu_tilde)
    above0, above1 = a > k0, a > k1
    zone = _zone(above0, above1, k0, k1)
    # k1 ≤ k0: no middle zone (and (k1 − |ν̃|)/1e-300 would overflow)
    span = max(k1 - k0, 1e-300)
    mid = (k0 / np.where(a > 0, a, 1.0)) * ((k1 - a) / span) ** 2 if k1 > k0 else 0.0
    w = np.where(above1, 0.0, np.where(above0, mid, 1.0))
    return w, zone


def rae_estimate(eta: Array, eta_ok: Array, H: Array, P_ref: Array, R0: Array, full: bool) -> Array:
    """Residual-based windowed R estimate (S1 eqs. 3/4, §4.2–4.3), batched.

    R̂ = (1/M) Σ_j η_j η_jᵀ + H P_ref Hᵀ over the window, where P_ref = P⁺_{k−1} (eq. 3) or P⁻_k
    (eq. 4). With missing channels (NaN measurements) each channel i averages over the c_i epochs
    it was present: Ŝ = D (Σ_j η_j η_jᵀ) D with D = diag(1/√c_i) and missing η entries set to 0.
    This keeps Ŝ positive semi-definite (a congruence of a PSD sum; an entry-wise average over
    pairwise counts is not) with the exact per-channel mean on the diagonal, shrinking only the
    cross terms of partly overlapping channels. A channel never present in the window gets
    R0_ii (and no cross terms). Without missing channels it is exactly S1's (1/M) Σ η ηᵀ.

    Parameters
    ----------
    eta : (B, M, m) residuals η_j = z_j − H x⁺_j of the last M epochs (any order).
    eta_ok : (B, M, m) bool, channel present at that epoch.
    H : (m, n) or (B, m, n); P_ref : (n, n) or (B, n, n).
    R0 : (m, m) nominal R, returned (broadcast) while the window is not full.
    full : the window holds M pushed residuals.
    """
    B, _, m = eta.shape
    R0 = np.asarray(R0, dtype=float)
    if not full:
        return np.broadcast_to(R0, (B, m, m)).copy()
    return sym(_residual_cov(eta, eta_ok, R0) + PHt(P_ref, H)[1])


def _residual_cov(eta: Array, eta_ok: Array, R0: Array) -> Array:
    """The window term Ŝ = D (Σ_j η_j η_jᵀ) D of :func:`rae_estimate` (B, m, m)."""
    if eta_ok.all():  # every channel present: D = I/√M, Ŝ = (1/M) Σ η ηᵀ
        return (mT(eta) @ eta) * (1.0 / eta.shape[1])
    m = eta.shape[-1]
    e = np.where(eta_ok, eta, 0.0)
    cnt = eta_ok.sum(axis=1)  # (B, m)
    dinv = np.where(cnt > 0, 1.0 / np.sqrt(np.maximum(cnt, 1)), 0.0)
    S_hat = (mT(e) @ e) * dinv[:, :, None] * dinv[:, None, :]
    return S_hat + np.where(cnt == 0, np.diag(R0), 0.0)[:, :, None] * np.eye(m)


# ------------------------------------------------------------------------------ helpers


def _flag_fix(flags: Array, fixed: Array) -> None:
    """Set flag 9 on still-accepted channels where a numerical fix was applied.

    ``fixed`` is (B,) (the whole run, e.g. a singular S) or (B, m) (the channels concerned).
    """
    fixed = np.asarray(fixed, dtype=bool)
    if fixed.any():
        flags[(fixed[:, None] if fixed.ndim == 1 else fixed) & (flags == ACCEPTED)] = NUMERICAL_FIX


def _eig_inside(R: Array, lo: float, hi: float) -> Array:
    """(B,) True where every eigenvalue of symmetric R certainly lies inside (lo, hi).

    m = 2: the closed-form eigenvalues (a + c ∓ √((a − c)² + 4b²))/2; otherwise Gershgorin
    discs (each eigenvalue lies within R_ii ± Σ_j≠i |R_ij| of some i). Either is accurate to a
    few ulp of max |λ| < hi, far inside the margin δ = 1e-9·hi; NaN compares False. False only
    means "not sure".
    """
    m = R.shape[-1]
    delta = 1e-9 * hi
    if m == 2:
        a, b, c = R[:, 0, 0], R[:, 0, 1], R[:, 1, 1]
        t, r = a + c, np.hypot(a - c, b + b)  # 2·mid, 2·radius
        return (t - r > 2.0 * (lo + delta)) & (t + r < 2.0 * (hi - delta))
    d = diag(R)
    rad = np.abs(R).sum(axis=-1) - np.abs(d)
    return np.all((d - rad > lo + delta) & (d + rad < hi - delta), axis=-1)


def _clamp(R: Array, lo: float, hi: float) -> tuple[Array, Array]:
    """Eigenvalue clamp of R̂ into [lo, hi] (§4.1 step 4), run by run.

    Returns ``(R', changed (B, m))`` where ``changed`` marks the channels whose variance R_ii the
    clamp moved (those get flag 9). A diverged run's non-finite R stays NaN (the experiment loop
    records the divergence) instead of stopping the whole batch.
    """
    R = sym(R)
    # fast path: a run whose eigenvalues are all inside (lo, hi) is unchanged by the clamp (eigh
    # would give back V diag(w) Vᵀ = R up to round-off), so only the other runs need an eigh
    inside = _eig_inside(R, lo, hi)
    changed = np.zeros(R.shape[:2], dtype=bool)
    if inside.all():
        return R, changed
    rest = ~inside
    Rr = R[rest]
    good = np.all(np.isfinite(Rr), axis=(-2, -1))
    out_r = np.full(Rr.shape, np.nan)
    if good.any():
        out_r[good], _ = eigh_clamp(Rr[good], lo, hi)
    with np.errstate(invalid="ignore"):
        d0, d1 = diag(Rr), diag(out_r)
        changed[rest] = ~good[:, None] | (np.abs(d1 - d0) > 1e-9 * np.maximum(np.abs(d0), lo))
    out = R.copy()
    out[rest] = out_r
    return out, changed


def _sqrt_factor(S: Array) -> tuple[Array, Array]:
    """Lower Cholesky factor L (L Lᵀ = S) of a batch; runs where S is not numerically positive
    definite (a diverging P) get the eigen-factor V·diag(√max(w, ε)) instead and are marked
    (flag 9) — run by run, so a healthy run never depends on its neighbours in the batch.
    """
    try:
        return np.linalg.cholesky(S), np.zeros(S.shape[0], dtype=bool)
    except np.linalg.LinAlgError:
        pass
    finite = np.all(np.isfinite(S), axis=(-2, -1))
    if not finite.all():
        L = np.full(S.shape, np.nan)
        bad = ~finite
        if finite.any():
            L[finite], bad[finite] = _sqrt_factor(S[finite])
        return L, bad
    w, V = np.linalg.eigh(sym(S))
    scale = np.maximum(np.abs(w).max(axis=-1, keepdims=True), 1e-300)
    bad = ~np.all(np.isfinite(w), axis=-1) | (w.min(axis=-1) <= 1e-12 * scale[..., 0])
    L = np.empty_like(S)
    if (~bad).any():
        L[~bad] = np.linalg.cholesky(S[~bad])
    if bad.any():
        wb = np.maximum(np.nan_to_num(w[bad]), 1e-12 * scale[bad])
        L[bad] = np.nan_to_num(V[bad]) * np.sqrt(wb)[:, None, :]
    return L, bad


def _zero_columns(K: Array, B: int, reject: Array) -> Array:
    """K with column i zeroed where reject[b, i]: (B, n, m)."""
    return bcast(K, (B, *K.shape[-2:])) * ~reject[:, None, :]


class _Window(NamedTuple):
    """Ring buffer of the last M posterior residuals of every run."""

    eta: Array  # (B, M, m)
    ok: Array  # (B, M, m) bool
    pushes: int

    @staticmethod
    def empty(B: int, M: int, m: int) -> _Window:
        return _Window(np.zeros((B, M, m)), np.zeros((B, M, m), dtype=bool), 0)

    @property
    def full(self) -> bool:
        return self.pushes >= self.eta.shape[1]

    def push(self, eta: Array, ok: Array) -> _Window:
        i = self.pushes % self.eta.shape[1]
        e, o = self.eta.copy(), self.ok.copy()
        e[:, i] = np.where(ok, eta, 0.0)
        o[:, i] = ok
        return _Window(e, o, self.pushes + 1)


def _sage_husa_R(
    R_prev: Array,
    nu: Array,
    HPHt: Array,
    ok: Array,
    d: float,
    lo: float,
    hi: float,
    diagonal: bool = False,
) -> tuple[Array, Array]:
    """R̂_k = (1 − d) R̂_{k−1} + d (ν νᵀ − H P⁻ Hᵀ), eigenvalues clamped into [lo, hi] (§4.1).

    Entries involving a missing channel keep their previous value. ``diagonal=True`` is the
    simplified per-channel form of §4.9 (off-diagonals 0, each diagonal entry clamped).
    Returns ``(R̂_k (B, m, m), clamped (B, m))``.
    """
    all_ok = ok.all()  # then the np.where below are identities
    nu0 = nu if all_ok else np.where(ok, nu, 0.0)
    if diagonal:
        r = (1.0 - d) * diag(R_prev) + d * (nu0**2 - diag(HPHt))
        if not all_ok:
            r = np.where(ok, r, diag(R_prev))
        clamped = (r < lo) | (r > hi)
        return diag_embed(np.minimum(np.maximum(r, lo), hi)), clamped
    new = (1.0 - d) * R_prev + d * (nu0[:, :, None] * nu0[:, None, :] - HPHt)
    if not all_ok:
        new = np.where(ok[:, :, None] & ok[:, None, :], new, R_prev)
    return _clamp(new, lo, hi)


def _scale_diag(A: Array, f: Array) -> Array:
    """A (B, m, m) with A_ii multiplied by f_i (B, m); off-diagonal entries unchanged."""
    B, m = f.shape
    out = bcast(A, (B, m, m)).copy()  # C-contiguous
    out.reshape(B, m * m)[:, :: m + 1] *= f
    return out


def _check_k0_k1(owner: str, k0: float, k1: float) -> None:
    if k1 < k0:
        raise NavlabError(f"filter '{owner}': k1 = {k1} must not be smaller than k0 = {k0}")


# ------------------------------------------------------------------------------ classic SHAKF


@dataclass(frozen=True)
class SageHusaParams:
    """Classic Sage–Husa options (ALGORITHMS.md §4.1)."""

    b: float = param(
        0.98,
        lo=0.5,
        hi=1.0,
        help="forgetting factor b (memory ≈ 1/(1−b) epochs; 1 = running average)",
    )
    adapt: bool = param(True, help="estimate R (off: R̂ stays R0 and the filter is the KF)")
    full: bool = param(False, help="full Sage–Husa: also estimate r̂, q̂ and Q̂ (ill-posed, may diverge)")


class SHState(NamedTuple):
    x: Array
    P: Array
    R: Array  # (B, m, m) current R̂
    k: int  # updates done
    r: Array  # (B, m) measurement-noise mean r̂
    Q: Array | None  # (B, n, n) Q̂ (full mode)
    q: Array  # (B, n) q̂
    x_prev: Array  # x⁺_{k−1}
    P_prev: Array  # P⁺_{k−1}


@register
class SageHusa(Filter):
    """Classic Sage–Husa adaptive KF: fading-memory innovation-based R̂ (ALGORITHMS.md §4.1)."""

    key = "sage-husa"
    label = "Sage–Husa AKF"
    family = "adaptive"
    paper = "Sage & Husa 1969"
    spec_section = "§4.1"
    summary = (
        "Estimates R recursively from the innovations with a forgetting factor b; no outlier "
        "protection (outliers inflate R̂)."
    )
    estimates_R = True
    Params = SageHusaParams

    def init(self, model: Model, x0: Array, P0: Array) -> SHState:
        x0 = np.array(x0, dtype=float)
        B, n = x0.shape
        m = model.m
        P = batched(np.asarray(P0, dtype=float), B).copy()
        R = batched(np.asarray(model.R0, dtype=float), B).copy()
        Q = None
        if self.params.full:
            Q = batched(np.asarray(model.Q(1), dtype=float), B).copy()
        return SHState(x0, P, R, 0, np.zeros((B, m)), Q, np.zeros((B, n)), x0, P)

    def predict(self, model: Model, state: SHState, k: int) -> SHState:
        F = model.F(k)
        x = model.f(state.x, k)
        Q = model.Q(k) if state.Q is None else state.Q
        if self.params.full:
            x = x + state.q
        P = predict_cov(F, state.P, Q)
        return state._replace(x=x, P=P, x_prev=state.x, P_prev=state.P)

    def update(self, model: Model, state: SHState, k: int, z: Array, side: SideInfo):
        p = self.params
        x_m, P_m = state.x, state.P
        B = z.shape[0]
        H = model.H(x_m, k)
        ok = np.isfinite(z)
        nu = z - model.h(x_m, k) - state.r
        U, HPHt = PHt(P_m, H)
        kk = state.k + 1
        flags = np.zeros(z.shape, dtype=np.int8)
        R = state.R
        d = forgetting_weight(kk, p.b)
        if p.adapt:
            lo, hi = _bounds(model.R0)
            R, clamped = _sage_husa_R(state.R, nu, HPHt, ok, d, lo, hi)  # (3)–(4)
            _flag_fix(flags, clamped)
        ok, nu_m, Hm, Rm = mask_missing(z, nu, H, R)
        if Hm is not H:
            U, HPHt = PHt(P_m, Hm)
        S = sym(HPHt + Rm)
        K, fixed = kf_gain(U, S)
        x = x_m + mv(K, nu_m)
        P = joseph_from_gain(P_m, K, U, S)
        _flag_fix(flags, fixed)
        r, q, Q = state.r, state.q, state.Q
        if p.full:  # optional full Sage–Husa (§4.1, off by default): noise means and Q̂
            r = np.where(ok, (1 - d) * state.r + d * (z - model.h(x_m, k)), state.r)
            Knu = mv(K, nu_m)
            F = model.F(k)
            Qn = (1 - d) * state.Q + d * (Knu[:, :, None] * Knu[:, None, :] + P - F @ state.P_prev @ mT(F))
            qmax = max(float(np.max(np.diag(np.asarray(model.Q(k), dtype=float)))), 1e-300)
            Q, _ = _clamp(Qn, 1e-6 * qmax, 1e6 * qmax)  # same PD guard as R̂
            q = (1 - d) * state.q + d * (x - model.f(state.x_prev, k))
        out = StepOut(
            x=x,
            P=P,
            innov=nu_m,
            S=S,
            R_used=Rm,
            R_hat=R,
            flags=flags,
            stats={"d_k": np.full(B, d)},
        )
        return state._replace(x=x, P=P, R=R, k=kk, r=r, q=q, Q=Q), out


# ------------------------------------------------------------------------------ IRAKF


@dataclass(frozen=True)
class IRAKFParams:
    """IRAKF options (ALGORITHMS.md §4.2–4.6, S1 = Ge, Zhang, Tang 2020)."""

    window: int = param(
        10,
        lo=1,
        hi=5000,
        help="RAE window M (epochs of residuals averaged; S1 gives none; R̂ = R0 until full)",
    )
    k0: float = param(1.5, lo=0.1, hi=1e6, help="down-weighting threshold k0 in σ (S1: 0.8–1.5)")
    k1: float = param(3.0, lo=0.1, hi=1e6, help="rejection threshold k1 in σ (S1: 3.0–5.0)")
    C: float = param(
        3.0, lo=0.1, hi=1e6, help="threshold factor C of the parallel-SKF detector, in σ (Fig. 1)"
    )
    dual_detection: bool = param(True, help="run the parallel standard KF detector (Fig. 1)")
    improved_rae: str = param(
        "conditional",
        choices=("conditional", "always", "never"),
        help="use P⁻ (eq. 4) instead of P⁺ₖ₋₁ (eq. 3) in R̂: on SKF detections / always / never",
    )
    middle_segment: str = param(
        "huber",
        choices=("huber", "literal"),
        help="middle-zone weight: Huber ν·k0/|ν̃| (default) or the seed's literal ν/c1",
    )
    middle_zone: str = param(
        "innovation",
        choices=("innovation", "variance"),
        help="apply the middle-zone weight to ν only, P updated as if unweighted (S1, default), "
        "or as an inflated variance R̂ᵢᵢ/w so P agrees (avoids a lock-out when P0 ≫ R)",
    )
    skf_gated: bool = param(
        False, help="also zero the parallel SKF's gain on its detections (locks out; spec §4.5)"
    )


class IRAKFState(NamedTuple):
    x: Array
    P: Array
    P_post: Array  # P⁺_{k−1}
    win: _Window
    xs: Array  # parallel SKF
    Ps: Array


@register
class IRAKF(Filter):
    """Improved robust adaptive KF (Ge, Zhang, Tang 2020; ALGORITHMS.md §4.6).

    Per epoch: (1) a parallel, ungated standard KF with the fixed R0 flags channels whose
    innovation exceeds C σ; (2) R̂ from the window of posterior residuals (eq. 3), with P⁻ in
    place of P⁺_{k−1} on flagged epochs (eq. 4); (3) per channel, ν̃ = ν/√S_ii: keep (≤ k0),
    Huber-shrink (≤ k1), or zero the gain column (> k1 or flagged by the SKF); (4) Joseph update,
    so P does not shrink on a rejected channel; (5) the raw posterior residual enters the window.
    """

    key = "irakf"
    label = "IRAKF"
    family = "robust-adaptive"
    paper = "Ge, Zhang, Tang 2020 (doi:10.19306/j.cnki.2095-8110.2020.01.007)"
    spec_section = "§4.2–4.6"
    summary = (
        "Windowed residual-based R̂, three-segment IGG/Huber weights that zero the gain of "
        "rejected channels, and a parallel standard KF as a second outlier detector."
    )
    estimates_R = True
    Params = IRAKFParams

    def __init__(self, params: Any = None, **kwargs: Any) -> None:
        super().__init__(params, **kwargs)
        _check_k0_k1(self.key, self.params.k0, self.params.k1)

    def init(self, model: Model, x0: Array, P0: Array) -> IRAKFState:
        x0 = np.array(x0, dtype=float)
        B = x0.shape[0]
        P = batched(np.asarray(P0, dtype=float), B).copy()
        win = _Window.empty(B, self.params.window, model.m)
        Ps = np.array(P0, dtype=float)  # the ungated SKF keeps a shared P if P0 is shared
        return IRAKFState(x0, P, P, win, x0.copy(), Ps)

    def predict(self, model: Model, state: IRAKFState, k: int) -> IRAKFState:
        F = model.F(k)
        Q = model.Q(k)
        x = model.f(state.x, k)
        P = predict_cov(F, state.P, Q)
        if self.params.dual_detection:
            xs = model.f(state.xs, k)
            Ps = predict_cov(F, state.Ps, Q)
        else:
            xs, Ps = state.xs, state.Ps
        return state._replace(x=x, P=P, P_post=state.P, xs=xs, Ps=Ps)

    def _skf_step(self, model: Model, state: IRAKFState, k: int, z: Array):
        """Parallel SKF (§4.5): detection flags from its own innovation, then its own update."""
        p = self.params
        B, m = z.shape
        if not p.dual_detection:
            return np.zeros((B, m), dtype=bool), np.zeros((B, m)), state.xs, state.Ps
        Hs = model.H(state.xs, k)
        nu_s = z - model.h(state.xs, k)
        ok, nu_s, Hs, Rs = mask_missing(z, nu_s, Hs, model.R0)
        Us, HPHs = PHt(state.Ps, Hs)
        Ss = sym(HPHs + Rs)
        nt_s = nu_s / np.sqrt(diag(Ss))
        flag_s = (np.abs(nt_s) > p.C) & ok
        # the standard KF update (kalman.kf_update), reusing Ss; gated: detections' columns zeroed
        K, _ = kf_gain(Us, Ss)
        if p.skf_gated and flag_s.any():
            K = _zero_columns(K, B, flag_s)
        xs = state.xs + mv(K, nu_s)
        Ps = joseph_from_gain(state.Ps, K, Us, Ss)
        return flag_s, nt_s, xs, Ps

    def update(self, model: Model, state: IRAKFState, k: int, z: Array, side: SideInfo):
        p = self.params
        B, m = z.shape
        # 1 parallel SKF: detection, then its own (ungated) update
        flag_s, nt_s, xs, Ps = self._skf_step(model, state, k, z)
        # 2 prior from predict(); 3 R̂ by RAE (eq. 3) or improved RAE (eq. 4)
        x_m, P_m = state.x, state.P
        H = model.H(x_m, k)
        if p.improved_rae == "always":
            use_prior = np.ones(B, dtype=bool)
        elif p.improved_rae == "never":
            use_prior = np.zeros(B, dtype=bool)
        else:
            use_prior = flag_s.any(axis=1)
        U, HPHt = PHt(P_m, H)
        flags = np.zeros((B, m), dtype=np.int8)
        if state.win.full:  # rae_estimate with P_ref = P⁻ or P⁺_{k−1} chosen after projecting
            HPH_ref = np.where(use_prior[:, None, None], HPHt, PHt(state.P_post, H)[1])
            R_hat = _residual_cov(state.win.eta, state.win.ok, model.R0) + HPH_ref
            lo, hi = _bounds(model.R0)  # eigenvalue guard (only bites with missing channels)
            R_hat, clamped = _clamp(R_hat, lo, hi)  # (symmetrises R̂)
            _flag_fix(flags, clamped)
        else:
            R_hat = batched(np.asarray(model.R0, dtype=float), B).copy()
        # 4 gain from the unmodified R̂
        nu_raw = z - model.h(x_m, k)
        ok, nu, Hm, Rm = mask_missing(z, nu_raw, H, R_hat)
        if Hm is not H:
            U, HPHt = PHt(P_m, Hm)
        S = sym(HPHt + Rm)
        K, fixed = kf_gain(U, S)
        sig = np.sqrt(diag(S))
        nt = nu / sig
        # 5 three-segment weights (eq. 7) + SKF detections: zero gain columns
        w, zone = irakf_weights(nt, p.k0, p.k1, p.middle_segment, sig)
        own_reject = (zone == 2) & ok
        aux_reject = flag_s & ~own_reject
        reject = own_reject | aux_reject
        down = (zone == 1) & ~reject & ok
        R_used = Rm
        if p.middle_zone == "variance" and down.any():
            # option (not S1): the Huber weight as an equivalent variance, so that K and P agree
            # with the down-weighting (S1 shrinks ν only: P then shrinks as if ν were unweighted,
            # which locks out when P⁻ ≫ R̂, e.g. the first epochs of an INS, see the report)
            infl = np.where(down, 1.0 / np.where(down, w, 1.0), 1.0)
            R_used = _scale_diag(Rm, infl)
            S_used = sym(HPHt + R_used)
            K, fixed2 = kf_gain(U, S_used)
            fixed = fixed | fixed2
            nu_w = nu
        else:
            S_used = S
            nu_w = np.where(down, w * nu, nu)
        if reject.any():
            K = _zero_columns(K, B, reject)
        # 6 state and Joseph covariance (P keeps the information of rejected channels out)
        x = x_m + mv(K, nu_w)
        P = joseph_from_gain(P_m, K, U, S_used)
        # 7 raw posterior residual into the window (rejected channels included, S1)
        eta = z - model.h(x, k)
        win = state.win.push(eta, ok)
        flags[down] = DOWNWEIGHTED
        flags[own_reject] = REJECTED
        flags[aux_reject] = REJECTED_AUX
        _flag_fix(flags, fixed)
        weights = np.where(reject, 0.0, np.where(down, w, 1.0))
        out = StepOut(
            x=x,
            P=P,
            innov=nu,
            S=S,
            R_used=R_used,
            R_hat=R_hat,
            weights=weights,
            flags=flags,
            stats={
                "nu_tilde": nt,
                "skf_nu_tilde": nt_s,
                "skf_flag": flag_s.astype(float),
                "improved_rae": use_prior.astype(float),
            },
        )
        return IRAKFState(x, P, P, win, xs, Ps), out


# ------------------------------------------------------------------------------ RRAE


@dataclass(frozen=True)
class RRAEParams:
    """RRAE options (ALGORITHMS.md §4.7, RECONSTRUCTION of Ge et al. 2018)."""

    window: int = param(10, lo=1, hi=5000, help="RAE window M (R̂ = R0 until full)")
    k0: float = param(1.5, lo=0.1, hi=1e6, help="IGG-III down-weighting threshold k0 in σ")
    k1: float = param(
        5.0,
        lo=0.1,
        hi=1e6,
        help="IGG-III rejection threshold k1 in σ (5 = top of S1's range; 3 locks out, §4.7)",
    )
    form: str = param(
        "equivalent_variance",
        choices=("equivalent_variance", "literal_scaling"),
        help="middle zone as an inflated variance R̂ᵢᵢ/wᵢ (default) or ν scaled by w "
        "(literal; locks out on clean data, spec uses k1 = 3 for it)",
    )


class RAEState(NamedTuple):
    x: Array
    P: Array
    P_post: Array
    win: _Window


@register
class RRAE(Filter):
    """Robust residual-based adaptive estimation (RECONSTRUCTION, ALGORITHMS.md §4.7).

    RAE R̂ (eq. 3, P⁺_{k−1}); IGG-III equivalent weights on ν̃ = ν/√S_ii: the middle zone enters
    as an inflated variance R̂_ii/w_i, the rejection zone sets ν_i = 0 while P is still updated
    with the short form (I − KH)P⁻ as if the measurement had been used — the scheme S1 criticises.
    """

    key = "rrae"
    label = "RRAE (reconstruction)"
    family = "robust-adaptive"
    paper = "Ge, Zhang, Sheng et al. 2018 (IEEE/CSAA GNC), cited as S1 ref. [16]"
    spec_section = "§4.7"
    summary = (
        "RECONSTRUCTION (paper not retrievable): windowed residual R̂ with classical IGG-III "
        "equivalent weights; rejected innovations are zeroed while P keeps shrinking."
    )
    reconstruction = True
    estimates_R = True
    Params = RRAEParams

    def __init__(self, params: Any = None, **kwargs: Any) -> None:
        super().__init__(params, **kwargs)
        _check_k0_k1(self.key, self.params.k0, self.params.k1)

    def init(self, model: Model, x0: Array, P0: Array) -> RAEState:
        x0 = np.array(x0, dtype=float)
        B = x0.shape[0]
        P = batched(np.asarray(P0, dtype=float), B).copy()
        return RAEState(x0, P, P, _Window.empty(B, self.params.window, model.m))

    def predict(self, model: Model, state: RAEState, k: int) -> RAEState:
        x = model.f(state.x, k)
        P = predict_cov(model.F(k), state.P, model.Q(k))
        return state._replace(x=x, P=P, P_post=state.P)

    def update(self, model: Model, state: RAEState, k: int, z: Array, side: SideInfo):
        p = self.params
        B, m = z.shape
        x_m, P_m = state.x, state.P
        H = model.H(x_m, k)
        # 1 RAE R̂ with P⁺_{k−1} (S1 eq. 3: rae_estimate, symmetrised by the clamp)
        flags = np.zeros((B, m), dtype=np.int8)
        if state.win.full:
            R_hat = _residual_cov(state.win.eta, state.win.ok, model.R0) + PHt(state.P_post, H)[1]
            lo, hi = _bounds(model.R0)
            R_hat, clamped = _clamp(R_hat, lo, hi)
            _flag_fix(flags, clamped)
        else:
            R_hat = batched(np.asarray(model.R0, dtype=float), B).copy()
        # 2 innovation statistics with R̂
        ok, nu, Hm, Rm = mask_missing(z, z - model.h(x_m, k), H, R_hat)
        U, HPHt = PHt(P_m, Hm)
        S = sym(HPHt + Rm)
        nt = nu / np.sqrt(diag(S))
        # 3 IGG-III equivalent weights
        w, zone = igg3_weights(nt, p.k0, p.k1)
        w = np.where(ok, w, 1.0)
        zone = np.where(ok, zone, 0)
        if p.form == "literal_scaling":
            R_bar = Rm
            nu_w = w * nu
        else:
            # 4 middle zone: equivalent variance R̄_ii = R̂_ii / w_i; rejection: ν_i ← 0
            mid = zone == 1
            infl = np.where(mid, 1.0 / np.where(mid, w, 1.0), 1.0)
            R_bar = _scale_diag(Rm, infl)
            nu_w = np.where(zone == 2, 0.0, nu)
        # 5 gain with R̄; short-form P (deliberately: P shrinks on zeroed channels, §4.7)
        S_bar = sym(HPHt + R_bar)
        K, fixed = kf_gain(U, S_bar)
        x = x_m + mv(K, nu_w)
        P = sym(P_m - K @ mT(U))  # (I − K H) P⁻, with H P⁻ = Uᵀ (P⁻ symmetric)
        # 6 posterior residual into the window
        win = state.win.push(z - model.h(x, k), ok)
        flags[zone == 1] = DOWNWEIGHTED
        flags[zone == 2] = REJECTED
        _flag_fix(flags, fixed)
        out = StepOut(
            x=x,
            P=P,
            innov=nu,
            S=S,
            R_used=R_bar,
            R_hat=R_hat,
            weights=w,
            flags=flags,
            stats={"nu_tilde": nt},
        )
        return RAEState(x, P, P, win), out


# ------------------------------------------------------------------------------ RAKF


@dataclass(frozen=True)
class RAKFParams:
    """RAKF options (ALGORITHMS.md §4.8, RECONSTRUCTION of Bai, Han, Qi 2012)."""

    b: float = param(0.98, lo=0.5, hi=1.0, help="Sage–Husa forgetting factor b")
    adapt: bool = param(True, help="estimate R by Sage–Husa (off: R̂ stays R0)")
    gamma_s: float = param(
        3.0,
        lo=0.1,
        hi=1e12,
        help="reserve coefficient γ_s of the divergence test νᵀν > γ_s·tr(S) (large = off)",
    )
    c: float = param(
        2.0,
        lo=0.1,
        hi=1e12,
        help="Huber clip c of the whitened innovation L_S⁻¹ν (large = no clipping)",
    )


class RAKFState(NamedTuple):
    x: Array
    P: Array
    R: Array
    k: int


@register
class RAKF(Filter):
    """Improved Sage–Husa KF of Bai et al. 2012 (RECONSTRUCTION, ALGORITHMS.md §4.8).

    Sage–Husa R̂; if νᵀν > γ_s·tr(H P⁻ Hᵀ + R̂) the prior covariance is inflated by
    λ = max(1, (νᵀν − tr R̂)/tr(H P⁻ Hᵀ)) (divergence suppression — the filter then trusts the
    measurement more); the innovation is Huber-clipped in whitened coordinates,
    ν' = L ψ_c(L⁻¹ν) with S = L Lᵀ, which keeps its covariance structure.
    """

    key = "rakf"
    label = "RAKF (reconstruction)"
    family = "robust-adaptive"
    paper = "Bai, Han, Qi 2012 (Chinese Control Conference), cited as S1 ref. [17]"
    spec_section = "§4.8"
    summary = (
        "RECONSTRUCTION (from the abstract): Sage–Husa R̂, prior covariance inflated when the "
        "innovation is abnormally large, Huber clipping of the whitened innovation."
    )
    reconstruction = True
    estimates_R = True
    Params = RAKFParams

    def init(self, model: Model, x0: Array, P0: Array) -> RAKFState:
        x0 = np.array(x0, dtype=float)
        B = x0.shape[0]
        P = batched(np.asarray(P0, dtype=float), B).copy()
        return RAKFState(x0, P, batched(np.asarray(model.R0, dtype=float), B).copy(), 0)

    def update(self, model: Model, state: RAKFState, k: int, z: Array, side: SideInfo):
        p = self.params
        B, m = z.shape
        x_m, P_m = state.x, state.P
        H = model.H(x_m, k)
        kk = state.k + 1
        flags = np.zeros((B, m), dtype=np.int8)
        # 1–2 innovation and Sage–Husa R̂
        nu_raw = z - model.h(x_m, k)
        ok = np.isfinite(z)
        R = state.R
        U, HPHt = PHt(P_m, H)
        if p.adapt:
            lo, hi = _bounds(model.R0)
            d = forgetting_weight(kk, p.b)
            R, clamped = _sage_husa_R(state.R, nu_raw, HPHt, ok, d, lo, hi)
            _flag_fix(flags, clamped)
        ok, nu, Hm, Rm = mask_missing(z, nu_raw, H, R)
        if Hm is not H:
            U, HPHt = PHt(P_m, Hm)
        # 3 abnormality test and prior-covariance inflation
        nn = np.einsum("bi,bi->b", nu, nu)
        trHPH = np.trace(HPHt, axis1=-2, axis2=-1)
        trR = np.trace(Rm, axis1=-2, axis2=-1)
        abnormal = nn > p.gamma_s * (trHPH + trR)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = np.where(abnormal, np.maximum(1.0, (nn - trR) / np.maximum(trHPH, 1e-300)), 1.0)
        if abnormal.any():  # (λ = 1 elsewhere: the products are exact there)
            P_m, U, HPHt = (A * lam[:, None, None] for A in (P_m, U, HPHt))
        # 4 Huber clipping of the whitened innovation
        S = sym(HPHt + Rm)
        L, sfix = _sqrt_factor(S)
        _flag_fix(flags, sfix)
        # an eigen-factor (sfix) is not triangular: a general solve there
        e = solve_sym(L, nu[..., None])[0][..., 0] if sfix.any() else forward_subst(L, nu)
        ae = np.abs(e)
        clip = (ae > p.c) & ok
        psi = np.where(clip, p.c * np.sign(e), e)
        nu_c = mv(L, psi)
        # 5 update with the clipped innovation, Joseph form with R̂
        K, fixed = kf_gain(U, S)
        x = x_m + mv(K, nu_c)
        P = joseph_from_gain(P_m, K, U, S)
        flags[abnormal[:, None] & ok & (flags == ACCEPTED)] = EPOCH_ANOMALY
        flags[clip] = DOWNWEIGHTED
        _flag_fix(flags, fixed)
        weights = np.where(clip, p.c / np.where(clip, ae, 1.0), 1.0)
        out = StepOut(
            x=x,
            P=P,
            innov=nu,
            S=S,
            R_used=Rm,
            R_hat=R,
            weights=weights,
            flags=flags,
            stats={"lambda": lam},
        )
        return RAKFState(x, P, R, kk), out


# ------------------------------------------------------------------------------ RSSHAKF


@dataclass(frozen=True)
class RSSHAKFParams:
    """RSSHAKF options (ALGORITHMS.md §4.9, RECONSTRUCTION of Narasimhappa et al. 2016)."""

    b: float = param(0.98, lo=0.5, hi=1.0, help="Sage–Husa forgetting factor b")
    adapt: bool = param(True, help="estimate the diagonal R̂ (off: R̂ stays diag R0)")
    c_r: float = param(
        2.5, lo=0.1, hi=1e12, help="outlier threshold c_r on |ν̃| (variance inflation above it)"
    )
    exclude_outliers: bool = param(
        False,
        help="skip the Sage–Husa update on outlier channels (variant; inverts S1's ranking, §4.9)",
    )


@register
class RSSHAKF(Filter):
    """Robust simplified Sage–Husa KF (RECONSTRUCTION, ALGORITHMS.md §4.9).

    R-only, diagonal Sage–Husa; channels with |ν̃_i| > c_r (ν̃ from R̂_{k−1}) get their variance
    inflated by |ν̃_i|/c_r for this update; the Sage–Husa update then runs on every channel.
    """

    key = "rsshakf"
    label = "RSSHAKF (reconstruction)"
    family = "robust-adaptive"
    paper = "Narasimhappa, Sabat, Nayak 2016 (IEEE Sensors J. 16(10)), cited as S1 ref. [18]"
    spec_section = "§4.9"
    summary = (
        "RECONSTRUCTION (paper not retrievable): diagonal Sage–Husa R̂ with variance inflation "
        "of channels whose normalised innovation exceeds c_r."
    )
    reconstruction = True
    estimates_R = True
    Params = RSSHAKFParams

    def init(self, model: Model, x0: Array, P0: Array) -> RAKFState:
        x0 = np.array(x0, dtype=float)
        B = x0.shape[0]
        P = batched(np.asarray(P0, dtype=float), B).copy()
        R = np.diag(np.diag(np.asarray(model.R0, dtype=float)))  # diagonal R̂ (§4.9)
        return RAKFState(x0, P, batched(R, B).copy(), 0)

    def update(self, model: Model, state: RAKFState, k: int, z: Array, side: SideInfo):
        p = self.params
        B, m = z.shape
        x_m, P_m = state.x, state.P
        H = model.H(x_m, k)
        kk = state.k + 1
        flags = np.zeros((B, m), dtype=np.int8)
        nu_raw = z - model.h(x_m, k)
        # 1 normalised innovation with R̂_{k−1}
        ok, nu, Hm, Rm = mask_missing(z, nu_raw, H, state.R)
        U, HPHt = PHt(P_m, Hm)
        nt = nu / np.sqrt(diag(HPHt) + diag(Rm))  # diag of sym(H P⁻ Hᵀ + R̂_{k−1}), exactly
        # 2–3 outlier channels: variance inflation R_ii · |ν̃_i|/c_r
        out_ch = (np.abs(nt) > p.c_r) & ok
        infl = np.where(out_ch, np.abs(nt) / p.c_r, 1.0)
        R_used = _scale_diag(Rm, infl)
        # 4 standard update with R_used (Joseph)
        S = sym(HPHt + R_used)
        K, fixed = kf_gain(U, S)
        x = x_m + mv(K, nu)
        P = joseph_from_gain(P_m, K, U, S)
        # 5 simplified Sage–Husa on the diagonal (every channel unless exclude_outliers)
        R = state.R
        if p.adapt:
            lo, hi = _bounds(model.R0)
            upd = ok & ~out_ch if p.exclude_outliers else ok
            HPHt0 = HPHt if Hm is H else PHt(P_m, H)[1]
            R, clamped = _sage_husa_R(
                state.R, nu, HPHt0, upd, forgetting_weight(kk, p.b), lo, hi, diagonal=True
            )
            _flag_fix(flags, clamped)
        flags[out_ch] = DOWNWEIGHTED
        _flag_fix(flags, fixed)
        weights = np.where(out_ch, 1.0 / infl, 1.0)
        out = StepOut(
            x=x,
            P=P,
            innov=nu,
            S=S,
            R_used=R_used,
            R_hat=R,
            weights=weights,
            flags=flags,
            stats={"nu_tilde": nt},
        )
        return RAKFState(x, P, R, kk), out
