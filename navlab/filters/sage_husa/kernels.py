"""What the Sage–Husa family shares (ALGORITHMS.md §4).

The weight functions (S1 eq. 7, IGG-III) and the fading-memory weight, elementwise over runs and
channels; the residual window; the two R̂ steps, written for ONE run, one equation a line, and
looped over the runs by :class:`navlab.jit.RunStep` (compiled by numba; the same Python
uncompiled without it, and as the tests' oracle): the Sage–Husa R̂ (§4.1 steps 3–4) and the
residual-window R̂ of RAE (S1 eqs. 3–4), both kept in a band around the nominal R0 (§4.1 step 4);
and the family's two templates, KF updates in named steps that each filter extends by its own:
:class:`FadingMemory` (a Sage–Husa R̂ carried in the state: SHAKF, RAKF, RSSHAKF) and
:class:`RAE` (the residual window, a second detector and the window R̂: RRAE, IRAKF).
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import numpy as np

from navlab.errors import NavlabError
from navlab.filters.base import R_HAT_AT_BAND, Model
from navlab.filters.kalman import KalmanUpdate, Noise, Prior
from navlab.jit import Kernel, RunStep
from navlab.linalg import (
    CHOLESKY_LOWER,
    FORWARD_SUBSTITUTE,
    Array,
    PHt,
    batched,
    bcast,
    cholesky_lower,
    diag,
    forward_substitute,
    mask_missing,
    sym,
)

# ------------------------------------------------------------------------------ weights


def forgetting_weight(k: int, b: float) -> float:
    """Sage–Husa fading-memory weight d_k = (1 − b)/(1 − b^{k+1}), k = 1 at the first update (§4.1).

    b = 1 is the limit d_k = 1/(k + 1) (plain running average including the prior R0).
    """
    if k < 1:
        raise ValueError("k counts updates from 1")
    if b >= 1.0:
        return 1.0 / (k + 1)
    return (1.0 - b) / (1.0 - b ** (k + 1))


def _zones(a: Array, k0: float, k1: float) -> tuple[Array, Array, Array]:
    """|ν̃| > k0, |ν̃| > k1 and the zone code 0/1/2 (int8; NaN compares False: zone 0)."""
    above0, above1 = a > k0, a > k1
    return above0, above1, np.where(above1, 2, above0).astype(np.int8)


def irakf_weights(
    nu_tilde: Array, k0: float, k1: float, middle: str = "huber", sigma: Array | None = None
) -> tuple[Array, Array]:
    """Three-segment weights of S1 eq. 7 on normalised innovations ν̃ = ν/σ (§4.4).

    Returns ``(w, zone)``: the factor multiplying ν_i — 1 (|ν̃| ≤ k0, zone 0), k0/|ν̃| (Huber,
    k0 < |ν̃| ≤ k1, zone 1), 0 (|ν̃| > k1, zone 2: IRAKF zeroes the gain column there).
    ``middle="literal"`` is the seed's printed ν/c1 with c1 = k1·σ_i in measurement units (weight
    1/(k1 σ_i), dimensionally inconsistent; kept only for comparison; needs ``sigma``).
    """
    a = np.abs(nu_tilde)
    above0, above1, zone = _zones(a, k0, k1)
    middle_zone = above0 & ~above1
    if middle == "literal":
        if sigma is None:
            raise ValueError("middle='literal' needs sigma")
        with np.errstate(divide="ignore"):  # σ_i = 0 only outside the middle zone (ν̃ = ν/σ)
            mid = 1.0 / (k1 * sigma)
    else:
        mid = k0 / np.where(middle_zone, a, 1.0)  # k0/|ν̃| (|ν̃| > k0 ≥ 0 there)
    w = np.where(above1, 0.0, np.where(above0, mid, 1.0))
    return w, zone


def igg3_weights(nu_tilde: Array, k0: float, k1: float) -> tuple[Array, Array]:
    """Yang's IGG-III equivalent weights (§4.7 step 3): continuous, 1 → 0 between k0 and k1.

    w = 1 (|ν̃| ≤ k0); (k0/|ν̃|)·((k1 − |ν̃|)/(k1 − k0))² (k0 < |ν̃| ≤ k1); 0 (|ν̃| > k1).
    Returns ``(w, zone)`` with zone 0/1/2. With k1 ≤ k0 there is no middle zone.
    """
    a = np.abs(nu_tilde)
    above0, above1, zone = _zones(a, k0, k1)
    a_mid = np.where(above0 & ~above1, a, 1.0)  # |ν̃| in the middle zone (bounded: no overflow)
    span = k1 - k0 if k1 > k0 else 1.0
    mid = (k0 / a_mid) * ((k1 - a_mid) / span) ** 2
    w = np.where(above1, 0.0, np.where(above0, mid, 1.0))
    return w, zone


# ------------------------------------------------------------------------------ R̂ estimates


class Window(NamedTuple):
    """Ring buffer of the last M posterior residuals η of every run (S1 eq. 3)."""

    eta: Array  # (B, M, m), 0 where the channel was missing
    ok: Array  # (B, M, m) bool, channel present at that epoch
    pushes: int

    @staticmethod
    def empty(B: int, M: int, m: int) -> Window:
        return Window(np.zeros((B, M, m)), np.zeros((B, M, m), dtype=bool), 0)

    @property
    def full(self) -> bool:
        return self.pushes >= self.eta.shape[1]

    def push(self, eta: Array, ok: Array) -> Window:
        i = self.pushes % self.eta.shape[1]
        e, o = self.eta.copy(), self.ok.copy()
        e[:, i] = np.where(ok, eta, 0.0)
        o[:, i] = ok
        return Window(e, o, self.pushes + 1)


def band(model: Any, params: Any) -> tuple[Array, Array, float, float]:
    """The nominal R0, its Cholesky factor L0 and the band [r_min, r_max] R̂ is kept in (§4.1 step 4)."""
    R0 = np.asarray(model.R0, dtype=float)
    return R0, _cholesky(R0.tobytes(), R0.shape[0]), float(params.r_min), float(params.r_max)


@functools.lru_cache(maxsize=32)
def _cholesky(R0: bytes, m: int) -> Array:
    try:
        return np.linalg.cholesky(np.frombuffer(R0).reshape(m, m))
    except np.linalg.LinAlgError:
        raise NavlabError("the nominal measurement noise R0 must be positive definite") from None


# The R̂ steps, written for ONE run (navlab.jit.RunStep loops them over the runs, compiled) -------


def clamp_to_band(R, R0, L0, lo, hi):  # pragma: no cover - compiled by numba
    """R̂ symmetrised and kept within [lo, hi] × R0 (§4.1 step 4), for ONE run.

    The eigenvalues of R̂ relative to the nominal R0 = L0 L0ᵀ (those of L0⁻¹ R̂ L0⁻ᵀ) are clamped
    into [lo, hi]: with R0 = σ² I, R̂'s eigenvalues into [lo σ², hi σ²]. Returns ``(R', changed
    (m,))``: ``changed`` marks the channels whose variance R_ii the clamp moved (flag 6). A
    diverged run's non-finite R̂ comes back NaN, every channel marked (the experiment loop records
    the divergence) instead of stopping the whole batch.
    """
    m = R.shape[0]
    out = np.empty((m, m))
    changed = np.zeros(m, dtype=np.bool_)
    finite = True
    for i in range(m):
        for j in range(m):
            out[i, j] = 0.5 * (R[i, j] + R[j, i])
            finite = finite and np.isfinite(out[i, j])
    if not finite:
        out[:] = np.nan
        changed[:] = True
        return out, changed
    A, L = np.empty((2, m, m))  # work arrays
    for i in range(m):
        for j in range(m):
            A[i, j] = out[i, j] - lo * R0[i, j]
    if cholesky_lower(A, L):
        for i in range(m):
            for j in range(m):
                A[i, j] = hi * R0[i, j] - out[i, j]
        if cholesky_lower(A, L):
            return out, changed  # lo R0 ≺ R̂ ≺ hi R0: inside the band, nothing to clamp
    W = out.copy()
    forward_substitute(L0, W)  # L0⁻¹ R̂
    W = W.T.copy()
    forward_substitute(L0, W)  # L0⁻¹ R̂ L0⁻ᵀ (symmetric up to round-off)
    w, V = np.linalg.eigh(0.5 * (W + W.T))
    if w.min() >= lo and w.max() <= hi:
        return out, changed
    w = np.minimum(np.maximum(w, lo), hi)
    C = (V * w) @ np.ascontiguousarray(V.T)  # the clamped L0⁻¹ R̂ L0⁻ᵀ
    new = L0 @ C @ np.ascontiguousarray(L0.T)  # back: L0 (…) L0ᵀ
    for i in range(m):
        changed[i] = abs(new[i, i] - out[i, i]) > 1e-9 * max(abs(out[i, i]), lo * R0[i, i])
        for j in range(m):
            out[i, j] = 0.5 * (new[i, j] + new[j, i])
    return out, changed


CLAMP_TO_BAND = Kernel(clamp_to_band, uses=(CHOLESKY_LOWER, FORWARD_SUBSTITUTE))


def sage_husa_rhat(R_prev, nu, M, ok, R0, L0, lo, hi, d, diagonal):  # pragma: no cover - compiled by numba
    """R̂_k = (1 − d) R̂_{k−1} + d (ν νᵀ − H P⁻ Hᵀ), kept in [lo, hi] × R0 (§4.1 steps 3–4), ONE run.

    M = H P⁻ Hᵀ; the entries of a channel not in ``ok`` keep R̂_{k−1}. ``diagonal``: the
    simplified per-channel form of §4.9 (off-diagonals 0, each variance in [lo, hi] × R0_ii).
    Returns ``(R̂_k, clamped (m,))``.
    """
    m = nu.shape[0]
    R = R_prev.copy()
    for i in range(m):
        for j in range(m):
            if ok[i] and ok[j]:
                R[i, j] = (1.0 - d) * R_prev[i, j] + d * (nu[i] * nu[j] - M[i, j])  # (3)
    if not diagonal:
        return clamp_to_band(R, R0, L0, lo, hi)  # (4)
    clamped = np.zeros(m, dtype=np.bool_)
    for i in range(m):  # §4.9: a diagonal R̂, each variance in its band
        clamped[i] = R[i, i] < lo * R0[i, i] or R[i, i] > hi * R0[i, i]
        r = min(max(R[i, i], lo * R0[i, i]), hi * R0[i, i])
        R[i, :] = 0.0
        R[i, i] = r
    return R, clamped


SAGE_HUSA_RHAT = RunStep(sage_husa_rhat, n_runs=4, outs=((0, float), (1, bool)), uses=(CLAMP_TO_BAND,))


def rae_rhat(eta, ok, HPH_ref, R0, L0, lo, hi):  # pragma: no cover - compiled by numba
    """R̂ = (1/M) Σ η_j η_jᵀ + H P_ref Hᵀ over the window, clamped (S1 eqs. 3/4, §4.2–4.3), ONE run.

    eta (M, m): the last M posterior residuals (0 where missing), ok (M, m): channel present,
    HPH_ref = H P_ref Hᵀ with P_ref = P⁺_{k−1} (eq. 3) or P⁻_k (eq. 4). With missing channels each
    channel i averages over the c_i epochs it was present: Ŝ = D (Σ_j η_j η_jᵀ) D,
    D = diag(1/√c_i) (a congruence of a PSD sum, so Ŝ stays PSD, with the exact per-channel mean
    on the diagonal); a channel never present gets R0_ii. Without missing channels it is exactly
    S1's (1/M) Σ η ηᵀ.
    """
    n_win, m = eta.shape
    dinv = np.zeros(m)
    for i in range(m):
        c = 0
        for t in range(n_win):
            c += ok[t, i]
        if c > 0:
            dinv[i] = 1.0 / np.sqrt(c)
    R = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            s = 0.0
            for t in range(n_win):
                s += eta[t, i] * eta[t, j]
            R[i, j] = s * dinv[i] * dinv[j] + HPH_ref[i, j]  # (3) R̂ = Ŝ + H P_ref Hᵀ
        if dinv[i] == 0.0:
            R[i, i] += R0[i, i]
    return clamp_to_band(R, R0, L0, lo, hi)


RAE_RHAT = RunStep(
    rae_rhat, n_runs=3, outs=((2, float), (lambda eta, ok, HPH: HPH[:1], bool)), uses=(CLAMP_TO_BAND,)
)


# ------------------------------------------------------------------------------ small helpers


def scale_diag(A: Array, f: Array) -> Array:
    """A ((m, m) or (B, m, m)) with A_ii multiplied by f_i (B, m); off-diagonal entries unchanged."""
    B, m = f.shape
    out = bcast(A, (B, m, m)).copy()  # C-contiguous
    out.reshape(B, m * m)[:, :: m + 1] *= f
    return out


def equivalent_variance(R: Array, w: Array, where: Array) -> Array:
    """R with R_ii / w_i on the channels ``where`` (a weight w_i as an inflated variance)."""
    return scale_diag(R, np.where(where, 1.0 / np.where(where, w, 1.0), 1.0))


# ------------------------------------------------------------------------------ the fading-memory filters


class RState(NamedTuple):
    """Per-run state of the filters that carry their R̂ (RAKF, RSSHAKF; SHAKF's extends it): x, P,
    R̂ (B, m, m) and the number k of updates done (d_k counts them).
    """

    x: Array
    P: Array
    R: Array
    k: int


class FadingMemory(KalmanUpdate):
    """The KF update with a Sage–Husa R̂ carried in the state (SHAKF, RAKF, RSSHAKF, §4.1/4.8/4.9).

    The state starts from R̂_0 = R0 in every run; each update's noise/weight step (the filter's
    own) reports its R̂_k as ``Noise.R_hat``, which the next state keeps, with one more update
    counted for d_k.
    """

    estimates_R = True

    def init(self, model: Model, x0: Array, P0: Array) -> RState:
        x0 = np.array(x0, dtype=float)
        B = x0.shape[0]
        P, R = (batched(np.asarray(A, dtype=float), B).copy() for A in (P0, model.R0))
        return RState(x0, P, R, 0)

    def sage_husa(
        self, model: Model, state: RState, pr: Prior, ok: Array, diagonal: bool = False
    ) -> tuple[Array, Array, float]:
        """3–4  R̂_k on the channels ``ok``, kept in its band (§4.1; R̂_{k−1} without ``adapt``).

        Returns R̂_k, the channels the band moved (B, m) and d_k (k counted from 1).
        """
        d = forgetting_weight(state.k + 1, self.params.b)
        if not self.params.adapt:
            return state.R, np.zeros(ok.shape, dtype=bool), d
        step = (state.R, pr.mk.nu, pr.mk.M, ok)
        R, clamped = SAGE_HUSA_RHAT(step, (*band(model, self.params), d, diagonal))
        return R, clamped, d

    def next_state(self, model: Model, state: RState, k: int, z: Array, x: Array, P: Array, nz: Noise):
        """x⁺, P⁺ and the R̂_k this update reported; one more update counted."""
        return state._replace(x=x, P=P, R=nz.R_hat, k=state.k + 1, **nz.state)


# ------------------------------------------------------------------------------ the residual-window filters


class RAEState(NamedTuple):
    x: Array
    P: Array
    P_post: Array  # P⁺_{k−1}
    win: Window  # the last M posterior residuals
    skf: tuple[Array, Array] | None = None  # IRAKF's parallel standard KF: x_S, P_S (§4.5)


class Detection(NamedTuple):
    """A second outlier detector's verdict beside the filter's own weights (IRAKF's parallel SKF).

    flag (B, m): the channels it flags; use_prior (B,): the runs whose R̂ takes H P⁻ Hᵀ (eq. 4)
    instead of H P⁺_{k−1} Hᵀ (eq. 3); nu_tilde (B, m) and skf: the SKF's ν̃ and updated state.
    """

    flag: Array
    use_prior: Array
    nu_tilde: Array | None = None
    skf: tuple[Array, Array] | None = None


class RAE(KalmanUpdate):
    """Residual-based adaptive estimation (RAE) in named steps, shared by RRAE (§4.7) and IRAKF (§4.6).

    Per update: a second outlier detector (:meth:`detect`, none here), the window R̂ (S1 eqs. 3/4,
    :meth:`rhat`), ν̃ = ν/√S_ii and the filter's own weights (its ``weigh(mk, R, S, ν̃, σ, det)``
    returns the :class:`~navlab.filters.kalman.Noise`: RRAE's IGG-III, IRAKF's eq. 7), then the
    gain and posterior, and the posterior residual into the window (:meth:`next_state`).
    """

    family = "robust-adaptive"
    estimates_R = True

    def __init__(self, params: Any = None, **kwargs: Any) -> None:
        super().__init__(params, **kwargs)
        k0, k1 = self.params.k0, self.params.k1  # the thresholds of the three-segment weights
        if k1 < k0:
            raise NavlabError(f"filter '{self.key}': k1 = {k1} must not be smaller than k0 = {k0}")

    def init(self, model: Model, x0: Array, P0: Array) -> RAEState:
        x0 = np.array(x0, dtype=float)
        P = batched(np.asarray(P0, dtype=float), x0.shape[0]).copy()
        return RAEState(x0, P, P, Window.empty(x0.shape[0], self.params.window, model.m))

    def predict(self, model: Model, state: RAEState, k: int) -> RAEState:
        return super().predict(model, state, k)._replace(P_post=state.P)  # x⁻, P⁻; keep P⁺_{k−1}

    def noise(self, model: Model, state: RAEState, pr: Prior, z: Array) -> Noise:
        """The update's noise/weight step (§4.7 steps 1–4, §4.6 steps 1, 3–5)."""
        det = self.detect(model, state, pr.k, z)  # §4.6 1  a second outlier detector (IRAKF's SKF)
        R_hat, clamped = self.rhat(model, state, pr, det.use_prior)  # §4.7 1, §4.6 3  RAE R̂, its guard
        R = mask_missing(z, pr.mk.nu, R_hat).R
        S = sym(pr.mk.M + R)  # §4.7 2, §4.6 4  S = H P⁻ Hᵀ + R̂, ν̃_i = ν_i / √S_ii
        sig = np.sqrt(diag(S))
        nz = self.weigh(pr.mk, R, S, pr.mk.nu / sig, sig, det)  # the filter's weights, what they leave
        nz.R_hat = R_hat
        nz.flags[clamped & (nz.flags == 0)] = R_HAT_AT_BAND
        return nz

    def detect(self, model: Model, state: RAEState, k: int, z: Array) -> Detection:
        """A second outlier detector beside the filter's own weights: none (R̂ always by eq. 3)."""
        return Detection(np.zeros(z.shape, dtype=bool), np.zeros(z.shape[0], dtype=bool))

    def rhat(self, model: Model, state: RAEState, pr: Prior, use_prior: Array) -> tuple[Array, Array]:
        """R̂_k = (1/M) Σ η_j η_jᵀ + H P_ref Hᵀ (S1 eqs. 3/4), R0 until the window is full, clamped.

        P_ref = P⁻ (eq. 4) in the runs ``use_prior``, P⁺_{k−1} (eq. 3) elsewhere.
        """
        B, m = pr.mk.nu.shape
        if not state.win.full:
            return batched(np.asarray(model.R0, dtype=float), B).copy(), np.zeros((B, m), dtype=bool)
        P_ref = np.where(use_prior[:, None, None], pr.P, state.P_post) if use_prior.any() else state.P_post
        return RAE_RHAT((state.win.eta, state.win.ok, PHt(P_ref, pr.H)[1]), band(model, self.params))

    def next_state(self, model: Model, state: RAEState, k: int, z: Array, x: Array, P: Array, nz: Noise):
        """The posterior residual η_k = z − H x⁺ into the window."""
        win = state.win.push(z - model.h(x, k), np.isfinite(z))
        return state._replace(x=x, P=P, P_post=P, win=win, **nz.state)
