"""The pure kernels the Sage–Husa family shares (ALGORITHMS.md §4), batched over runs.

Weight functions (S1 eq. 7, IGG-III), the fading-memory weight and the R̂ guard of Sage–Husa
(§4.1), the residual-window estimate RAE (S1 eqs. 3–4), and the small helpers the filters use
(gain-column zeroing, diagonal scaling, the residual window). Tests and the app call them on
their own.

Speed trick kept here (``python benchmarks/tricks.py --trick clamp-eig-inside``): :func:`clamp_eig`
runs the eigen-decomposition only for the runs whose eigenvalues are not certainly inside the
bounds (:func:`eig_inside`); a run certainly inside is returned unchanged, which is what the
eigen-clamp would give back up to round-off.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from navlab.errors import NavlabError
from navlab.jit import Kernel, carray
from navlab.linalg import (
    CHOLESKY_LOWER,
    Array,
    bcast,
    cholesky_lower,
    diag,
    diag_embed,
    eigh_clamp,
    mT,
    select,
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


def check_k0_k1(owner: str, k0: float, k1: float) -> None:
    """NavlabError unless k0 ≤ k1 (the thresholds of the three-segment weights)."""
    if k1 < k0:
        raise NavlabError(f"filter '{owner}': k1 = {k1} must not be smaller than k0 = {k0}")


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


def rae_estimate(win: Window, HPH_ref: Array, R0: Array) -> Array:
    """Residual-based windowed R estimate (S1 eqs. 3/4, §4.2–4.3), batched: (B, m, m).

    R̂ = (1/M) Σ_j η_j η_jᵀ + H P_ref Hᵀ over the window, where P_ref = P⁺_{k−1} (eq. 3) or P⁻_k
    (eq. 4) and ``HPH_ref`` = H P_ref Hᵀ; R0 (broadcast) while the window is not full. With
    missing channels (NaN measurements) each channel i averages over the c_i epochs it was
    present: Ŝ = D (Σ_j η_j η_jᵀ) D with D = diag(1/√c_i) and missing η entries 0. This keeps Ŝ
    positive semi-definite (a congruence of a PSD sum; an entry-wise average over pairwise counts
    is not) with the exact per-channel mean on the diagonal, shrinking only the cross terms of
    partly overlapping channels. A channel never present in the window gets R0_ii (and no cross
    terms). Without missing channels it is exactly S1's (1/M) Σ η ηᵀ.
    """
    B, _, m = win.eta.shape
    R0 = np.asarray(R0, dtype=float)
    if not win.full:
        return np.broadcast_to(R0, (B, m, m)).copy()
    eta = win.eta
    if win.ok.all():  # every channel present: D = I/√M, Ŝ = (1/M) Σ η ηᵀ   (eq. 3)
        S_hat = (mT(eta) @ eta) * (1.0 / eta.shape[1])
    else:
        e = np.where(win.ok, eta, 0.0)
        cnt = win.ok.sum(axis=1)  # (B, m)
        dinv = np.where(cnt > 0, 1.0 / np.sqrt(np.maximum(cnt, 1)), 0.0)
        S_hat = (mT(e) @ e) * dinv[:, :, None] * dinv[:, None, :]
        S_hat = S_hat + np.where(cnt == 0, np.diag(R0), 0.0)[:, :, None] * np.eye(m)
    return sym(S_hat + HPH_ref)


def rhat_bounds(R0: Array) -> tuple[float, float]:
    """Eigenvalue clamp [r_min, r_max] = [0.01·min diag R0, 1e4·max diag R0] (§4.1 step 4)."""
    d = np.diagonal(np.asarray(R0, dtype=float))
    return 0.01 * float(d.min()), 1e4 * float(d.max())


def _inside_runs(R, lo, hi, out):  # pragma: no cover - compiled by numba
    """out[r] = every eigenvalue of R_r lies in (lo, hi): R − lo I and hi I − R positive definite.

    Each tested by a Cholesky factorisation (it succeeds exactly for a positive definite matrix,
    to a backward error of a few ulp of ‖R‖, far below the margin the caller adds to lo and hi).
    """
    B, m, _ = R.shape
    A = np.empty((m, m))
    L = np.empty((m, m))
    for r in range(B):
        for i in range(m):
            for j in range(m):
                A[i, j] = R[r, i, j]
            A[i, i] -= lo
        if not cholesky_lower(A, L):
            out[r] = False
            continue
        for i in range(m):
            for j in range(m):
                A[i, j] = -R[r, i, j]
            A[i, i] += hi
        out[r] = cholesky_lower(A, L)


_INSIDE = Kernel(_inside_runs, uses=(CHOLESKY_LOWER,))


def eig_inside(R: Array, lo: float, hi: float) -> Array:
    """(B,) True where every eigenvalue of symmetric R certainly lies inside (lo, hi).

    m = 2: the closed-form eigenvalues (a + c ∓ √((a − c)² + 4b²))/2. m ≥ 3, compiled
    (navlab.jit): R − (lo + δ) I and (hi − δ) I − R are positive definite, by Cholesky; the numpy
    path: Gershgorin discs (each eigenvalue lies within R_ii ± Σ_j≠i |R_ij| of some i), which is
    sure less often. Each is accurate to a few ulp of max |λ| < hi, far inside the margin
    δ = 1e-9·hi; NaN compares False. False only means "not sure".
    """
    m = R.shape[-1]
    delta = 1e-9 * hi
    kernel = _INSIDE.get() if m > 2 else None
    if kernel is not None:
        out = np.empty(R.shape[0], dtype=bool)
        kernel(carray(R), lo + delta, hi - delta, out)
        return out
    if m == 2:
        a, b, c = R[:, 0, 0], R[:, 0, 1], R[:, 1, 1]
        t, r = a + c, np.hypot(a - c, b + b)  # 2·mid, 2·radius
        return (t - r > 2.0 * (lo + delta)) & (t + r < 2.0 * (hi - delta))
    d = diag(R)
    rad = np.abs(R).sum(axis=-1) - np.abs(d)
    return np.all((d - rad > lo + delta) & (d + rad < hi - delta), axis=-1)


def clamp_eig(R: Array, lo: float, hi: float) -> tuple[Array, Array]:
    """Eigenvalue clamp of R̂ into [lo, hi] (§4.1 step 4), run by run; symmetrises R.

    Returns ``(R', changed (B, m))`` where ``changed`` marks the channels whose variance R_ii the
    clamp moved (those get flag 9). A diverged run's non-finite R stays NaN (the experiment loop
    records the divergence) instead of stopping the whole batch.
    """
    R = sym(R)
    # fast path: a run whose eigenvalues are all inside (lo, hi) is unchanged by the clamp (eigh
    # would give back V diag(w) Vᵀ = R up to round-off), so only the other runs need an eigh
    inside = eig_inside(R, lo, hi)
    changed = np.zeros(R.shape[:2], dtype=bool)
    if inside.all():
        return R, changed
    rest = ~inside
    Rr = R[rest]
    good = np.all(np.isfinite(Rr), axis=(-2, -1))
    out_r = np.full(Rr.shape, np.nan)
    if good.any():
        out_r[good], _ = eigh_clamp(Rr[good], lo, hi)
    d0, d1 = diag(Rr), diag(out_r)
    with np.errstate(invalid="ignore"):  # a diverged run's NaN/inf R: marked changed below
        moved = np.abs(d1 - d0) > 1e-9 * np.maximum(np.abs(d0), lo)
    changed[rest] = ~good[:, None] | moved
    out = R.copy()
    out[rest] = out_r
    return out, changed


def sage_husa_R(
    R_prev: Array,
    nu: Array,
    HPHt: Array,
    ok: Array,
    d: float,
    lo: float,
    hi: float,
    diagonal: bool = False,
) -> tuple[Array, Array]:
    """R̂_k = (1 − d) R̂_{k−1} + d (ν νᵀ − H P⁻ Hᵀ), eigenvalues clamped into [lo, hi] (§4.1 3–4).

    Entries involving a missing channel keep their previous value. ``diagonal=True`` is the
    simplified per-channel form of §4.9 (off-diagonals 0, each diagonal entry clamped).
    Returns ``(R̂_k (B, m, m), clamped (B, m))``.
    """
    present = None if ok.all() else ok  # (None: every channel present, nothing to keep)
    nu0 = select(present, nu, 0.0)
    if diagonal:
        r = (1.0 - d) * diag(R_prev) + d * (nu0**2 - diag(HPHt))
        r = select(present, r, diag(R_prev))
        clamped = (r < lo) | (r > hi)
        return diag_embed(np.minimum(np.maximum(r, lo), hi)), clamped
    new = (1.0 - d) * R_prev + d * (nu0[:, :, None] * nu0[:, None, :] - HPHt)
    new = select(None if present is None else ok[:, :, None] & ok[:, None, :], new, R_prev)
    return clamp_eig(new, lo, hi)


# ------------------------------------------------------------------------------ small helpers


def scale_diag(A: Array, f: Array) -> Array:
    """A ((m, m) or (B, m, m)) with A_ii multiplied by f_i (B, m); off-diagonal entries unchanged."""
    B, m = f.shape
    out = bcast(A, (B, m, m)).copy()  # C-contiguous
    out.reshape(B, m * m)[:, :: m + 1] *= f
    return out


def sqrt_factor(S: Array) -> tuple[Array, Array]:
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
            L[finite], bad[finite] = sqrt_factor(S[finite])
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


class RState(NamedTuple):
    """Per-run state of the filters that carry their R̂ (RAKF, RSSHAKF): x, P, R̂ (B, m, m) and the
    number k of updates done (d_k counts them).
    """

    x: Array
    P: Array
    R: Array
    k: int
