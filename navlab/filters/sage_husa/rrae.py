"""RRAE — robust residual-based adaptive estimation (RECONSTRUCTION; ALGORITHMS.md §4.7).

S1 ref. [16] (Ge et al. 2018) could not be retrieved; navlab's reading, in §4.7's numbering::

    1  x⁻, P⁻ ;  R̂_k by RAE eq. 3 (P⁺_{k−1}), R0 until the window (M = 10) is full
    2  S = H P⁻ Hᵀ + R̂_k ;  ν = z − H x⁻ ;  ν̃_i = ν_i / √S_ii
    3  IGG-III equivalent weights w_i (k0 = 1.5, k1 = 5)
    4  middle zone: R̄_ii = R̂_k,ii / w_i ;  rejection zone: ν_i ← 0, R̄_ii = R̂_k,ii
    5  K = P⁻ Hᵀ (H P⁻ Hᵀ + R̄)⁻¹ ;  x⁺ = x⁻ + K ν ;  P⁺ = (I − K H) P⁻  (short form on purpose)
    6  η_k = z − H x⁺ into the window
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from navlab.filters.base import R_HAT_AT_BAND, KFLimit, Model, Teaching, band_param, register
from navlab.filters.kalman import KalmanUpdate, Noise, Prior
from navlab.filters.sage_husa.kernels import (
    RAE_RHAT,
    Window,
    band,
    check_k0_k1,
    igg3_weights,
    scale_diag,
)
from navlab.linalg import Array, Masked, PHt, batched, diag, kf_gain, mask_missing, mT, predict_cov, sym
from navlab.params import param


@dataclass(frozen=True)
class RRAEParams:
    """RRAE options (ALGORITHMS.md §4.7, RECONSTRUCTION of Ge et al. 2018)."""

    window: int = param(10, lo=1, hi=5000, tune=(3, 100), help="RAE window M (R̂ = R0 until full)")
    k0: float = param(1.5, lo=0.1, hi=1e6, tune=(0.5, 3.0), help="IGG-III down-weighting threshold k0 in σ")
    k1: float = param(
        5.0,
        lo=0.1,
        hi=1e6,
        tune=(2.0, 10.0),
        help="IGG-III rejection threshold k1 in σ (5 = top of S1's range; 3 locks out, §4.7)",
    )
    form: str = param(
        "equivalent_variance",
        choices=("equivalent_variance", "literal_scaling"),
        help="middle zone as an inflated variance R̂ᵢᵢ/wᵢ (default) or ν scaled by w "
        "(literal; locks out on clean data, spec uses k1 = 3 for it)",
    )
    r_min: float = band_param("r_min")
    r_max: float = band_param("r_max")


class RAEState(NamedTuple):
    x: Array
    P: Array
    P_post: Array
    win: Window


@register
class RRAE(KalmanUpdate):
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
    kf_limit = KFLimit(
        {"window": 5000, "k0": 1e6, "k1": 1e6},
        why="a window longer than the run keeps R̂ = R0; thresholds → ∞ keep every weight 1",
    )
    teaching = Teaching(
        idea=(
            "Robust residual-based adaptive estimation (a reconstruction of Ge et al. 2018): R from "
            "a window of posterior residuals, and Yang's IGG-III equivalent weights — full weight "
            "for small innovations, a smoothly shrinking weight (as an inflated variance) in the "
            "middle, and the innovation set to zero beyond k₁ while P still shrinks, the weakness "
            "the IRAKF paper points out."
        ),
        equations=(
            r"\hat R_k = \frac1M \sum_{j=k-M}^{k-1}\eta_j\eta_j^\top + H P^+_{k-1} H^\top",
            r"w_i = \begin{cases} 1 & |\tilde\nu_i| \le k_0 \\ \dfrac{k_0}{|\tilde\nu_i|}"
            r"\left(\dfrac{k_1 - |\tilde\nu_i|}{k_1 - k_0}\right)^2 & k_0 < |\tilde\nu_i| \le k_1 \\"
            r" 0 & |\tilde\nu_i| > k_1 \end{cases}",
            r"\bar R_{ii} = \hat R_{k,ii}/w_i \ (0<w_i<1), \qquad \nu_i \leftarrow 0\ (w_i = 0)",
            r"K = P^- H^\top (H P^- H^\top + \bar R)^{-1}, \quad x^+ = x^- + K\nu, \quad "
            r"P^+ = (I - KH)P^-",
        ),
    )

    def __init__(self, params: Any = None, **kwargs: Any) -> None:
        super().__init__(params, **kwargs)
        check_k0_k1(self.key, self.params.k0, self.params.k1)

    def init(self, model: Model, x0: Array, P0: Array) -> RAEState:
        x0 = np.array(x0, dtype=float)
        B = x0.shape[0]
        P = batched(np.asarray(P0, dtype=float), B).copy()
        return RAEState(x0, P, P, Window.empty(B, self.params.window, model.m))

    def predict(self, model: Model, state: RAEState, k: int) -> RAEState:
        x = model.f(state.x, k)
        P = predict_cov(model.F(k), state.P, model.Q(k))
        return state._replace(x=x, P=P, P_post=state.P)

    # The update in named steps (§4.7's numbering; IRAKF overrides its own, §4.6) ---------------
    def noise(self, model: Model, state: RAEState, pr: Prior, z: Array) -> Noise:
        det = self.detect(model, state, pr.k, z)  # a second outlier detector (none here)
        R_hat, clamped = self.rhat(model, state, pr, det)  # 1  RAE R̂ (eq. 3), eigenvalue guard
        R = mask_missing(z, pr.mk.nu, R_hat).R
        S = sym(pr.mk.M + R)  # 2  S = H P⁻ Hᵀ + R̂, ν̃_i = ν_i / √S_ii
        sig = np.sqrt(diag(S))
        nz = self.weigh(pr.mk, R, S, pr.mk.nu / sig, sig, det)  # 3–4  the weights and what they leave
        nz.R_hat = R_hat
        nz.flags[clamped & (nz.flags == 0)] = R_HAT_AT_BAND
        return nz

    def detect(self, model: Model, state: RAEState, k: int, z: Array) -> Any:
        """A second outlier detector beside the filter's own weights (RRAE has none)."""
        return None

    def use_prior(self, det: Any, B: int) -> Array:
        """(B,) True where R̂ takes H P⁻ Hᵀ (eq. 4) instead of H P⁺ₖ₋₁ Hᵀ (eq. 3): never here."""
        return np.zeros(B, dtype=bool)

    def rhat(self, model: Model, state: RAEState, pr: Prior, det: Any) -> tuple[Array, Array]:
        """R̂_k = (1/M) Σ η_j η_jᵀ + H P_ref Hᵀ (S1 eqs. 3/4), R0 until the window is full, clamped."""
        B, m = pr.mk.nu.shape
        if not state.win.full:
            return batched(np.asarray(model.R0, dtype=float), B).copy(), np.zeros((B, m), dtype=bool)
        use_prior = self.use_prior(det, B)  # P_ref = P⁻ (eq. 4) there, P⁺_{k−1} (eq. 3) elsewhere
        P_ref = np.where(use_prior[:, None, None], pr.P, state.P_post) if use_prior.any() else state.P_post
        r0 = np.broadcast_to(np.diag(np.asarray(model.R0, dtype=float)), (B, m))
        return RAE_RHAT((state.win.eta, state.win.ok, PHt(P_ref, pr.H)[1], r0), band(model, self.params))

    def weigh(self, mk: Masked, R: Array, S: Array, nt: Array, sig: Array, det: Any) -> Noise:
        """3–4  IGG-III weights; middle zone R̄_ii = R̂_ii / w_i, rejection zone ν_i ← 0 (flags 1, 2)."""
        p = self.params
        w, zone = igg3_weights(nt, p.k0, p.k1)  # 3  IGG-III equivalent weights
        w, zone = np.where(mk.ok, w, 1.0), np.where(mk.ok, zone, 0)
        if p.form == "literal_scaling":  # option: ν_i ← w_i ν_i in every zone, K and P from R̂
            R_bar, nu = R, w * mk.nu
        else:  # 4  middle zone: R̄_ii = R̂_ii / w_i; rejection zone: ν_i ← 0
            mid = zone == 1
            R_bar = scale_diag(R, np.where(mid, 1.0 / np.where(mid, w, 1.0), 1.0))
            nu = np.where(zone == 2, 0.0, mk.nu)
        flags = zone.astype(np.int8)  # 1 down-weighted (middle zone), 2 rejected
        return Noise(R_bar, weights=w, flags=flags, nu=nu, S=S, stats={"nu_tilde": nt})

    def gain(self, mk: Masked, S: Array, nz: Noise) -> tuple[Array, Array]:
        """5  K = P⁻ Hᵀ (H P⁻ Hᵀ + R̄)⁻¹: no column zeroed (a rejected ν_i is 0 instead)."""
        return kf_gain(mk.U, S)

    def posterior(self, pr: Prior, K: Array, S: Array) -> Array:
        """5  P⁺ = (I − K H) P⁻, the short form on purpose (P shrinks on zeroed channels, §4.7)."""
        return sym(pr.P - K @ mT(pr.mk.U))  # with H P⁻ = Uᵀ (P⁻ symmetric)

    def next_state(self, model: Model, state: RAEState, k: int, z: Array, x: Array, P: Array, nz: Noise):
        """6  The posterior residual η_k = z − H x⁺ into the window."""
        win = state.win.push(z - model.h(x, k), np.isfinite(z))
        return state._replace(x=x, P=P, P_post=P, win=win, **nz.state)
