"""Classic Sage–Husa adaptive KF (SHAKF, ALGORITHMS.md §4.1; Sage & Husa 1969).

Fading-memory estimate of R from the innovations, step by step (§4.1 numbering)::

    1  x⁻ = F x⁺ (+ q̂) ;  P⁻ = F P⁺ Fᵀ + Q̂
    2  ν = z − H x⁻ − r̂
    3  R̂_k = (1 − d_k) R̂_{k−1} + d_k (ν νᵀ − H P⁻ Hᵀ),   d_k = (1 − b)/(1 − b^{k+1})
    4  eigenvalues of R̂_k clamped into [0.01 min R0_ii, 1e4 max R0_ii] (flag 6 where clamped)
    5  KF update with R̂_k (Joseph form)
    optional (``full``): r̂, Q̂ (with the same guard) and q̂ by the same fading memory.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from navlab.filters.base import R_HAT_AT_BAND, KFLimit, Model, SideInfo, Teaching, band_param, register
from navlab.filters.kalman import Noise, Prior
from navlab.filters.sage_husa.kernels import FadingMemory, forgetting_weight
from navlab.linalg import Array, batched, eigh_clamp, mask_missing, mT, predict_cov
from navlab.params import param


@dataclass(frozen=True)
class SageHusaParams:
    """Classic Sage–Husa options (ALGORITHMS.md §4.1)."""

    b: float = param(
        0.98,
        lo=0.5,
        hi=1.0,
        tune=(0.8, 0.999),
        help="forgetting factor b (memory ≈ 1/(1−b) epochs; 1 = running average)",
    )
    adapt: bool = param(True, help="estimate R (off: R̂ stays R0 and the filter is the KF)")
    full: bool = param(False, help="full Sage–Husa: also estimate r̂, q̂ and Q̂ (ill-posed, may diverge)")
    r_min: float = band_param("r_min")
    r_max: float = band_param("r_max")


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
class SageHusa(FadingMemory):
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
    Params = SageHusaParams
    kf_limit = KFLimit({"adapt": False}, why="without adaptation R̂ stays R0")
    teaching = Teaching(
        idea=(
            "The Sage–Husa filter estimates R recursively from the innovations with a fading-memory "
            "weight d_k: R̂ moves towards ννᵀ − HP⁻Hᵀ, the measurement noise the innovation "
            "implies. It adapts to a changing noise level but has no outlier protection: one large "
            "innovation inflates R̂ at once. The estimate can lose positive definiteness, so it is "
            "clamped."
        ),
        equations=(
            r"d_k = \dfrac{1 - b}{1 - b^{k+1}}, \qquad b = 0.98",
            r"\nu_k = z_k - H x^-_k",
            r"\hat R_k = (1 - d_k)\hat R_{k-1} + d_k\left(\nu_k\nu_k^\top - H P^-_k H^\top\right)"
            r"\quad(\text{eigenvalues clamped})",
            r"K_k = P^-_k H^\top (H P^-_k H^\top + \hat R_k)^{-1}, \qquad x^+_k = x^-_k + K_k\nu_k",
        ),
    )

    def init(self, model: Model, x0: Array, P0: Array) -> SHState:
        st = super().init(model, x0, P0)
        B, n = st.x.shape
        Q = batched(np.asarray(model.Q(1), dtype=float), B).copy() if self.params.full else None
        return SHState(*st, np.zeros((B, model.m)), Q, np.zeros((B, n)), st.x, st.P)

    def predict(self, model: Model, state: SHState, k: int) -> SHState:
        x = model.f(state.x, k)  # 1  x⁻ = F x⁺ (+ q̂)
        if self.params.full:
            x = x + state.q
        Q = model.Q(k) if state.Q is None else state.Q
        P = predict_cov(model.F(k), state.P, Q)  # 1  P⁻ = F P⁺ Fᵀ + Q̂
        return state._replace(x=x, P=P, x_prev=state.x, P_prev=state.P)

    def innovation(self, model: Model, state: SHState, k: int, z: Array, side: SideInfo) -> Prior:
        return super().innovation(model, state, k, z - state.r, side)  # 2  ν = z − H x⁻ − r̂

    def noise(self, model: Model, state: SHState, pr: Prior, z: Array) -> Noise:
        """3–4  R̂_k, its eigenvalues clamped (flag 6 where a variance moved); 5 is the KF update."""
        R, clamped, d = self.sage_husa(model, state, pr, pr.mk.ok)  # 3  R̂_k, 4  its band
        flags = np.where(clamped, R_HAT_AT_BAND, 0).astype(np.int8)
        return Noise(
            mask_missing(z, pr.mk.nu, R).R, R_hat=R, flags=flags, stats={"d_k": np.full(z.shape[0], d)}
        )

    def next_state(
        self, model: Model, state: SHState, k: int, z: Array, x: Array, P: Array, nz: Noise
    ) -> SHState:
        """Optional full Sage–Husa (§4.1, off by default): the noise means r̂, q̂ and Q̂."""
        st = super().next_state(model, state, k, z, x, P, nz)
        if not self.params.full:
            return st
        d = forgetting_weight(st.k, self.params.b)  # this update's d_k
        r = np.where(np.isfinite(z), (1 - d) * state.r + d * (z - model.h(state.x, k)), state.r)
        Knu = x - state.x  # K ν = x⁺ − x⁻
        F = model.F(k)
        Qn = (1 - d) * state.Q + d * (Knu[:, :, None] * Knu[:, None, :] + P - F @ state.P_prev @ mT(F))
        qmax = max(float(np.max(np.diag(np.asarray(model.Q(k), dtype=float)))), 1e-300)
        Q, _ = eigh_clamp(Qn, 1e-6 * qmax, 1e6 * qmax)  # the same PD guard as R̂
        q = (1 - d) * state.q + d * (x - model.f(state.x_prev, k))
        return st._replace(r=r, q=q, Q=Q)
