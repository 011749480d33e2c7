"""RAKF — improved Sage–Husa KF for a MEMS inclinometer (RECONSTRUCTION; ALGORITHMS.md §4.8).

S1 ref. [17] (Bai, Han, Qi 2012) is known from its abstract only; navlab's reading, in §4.8's
numbering::

    1  x⁻ = F x⁺ ;  P⁻ = F P⁺ Fᵀ + Q ;  ν = z − H x⁻
    2  Sage–Husa R̂_k (§4.1, b = 0.98, eigenvalue guard)
    3  if νᵀν > γ_s tr(H P⁻ Hᵀ + R̂_k):  λ_k = max(1, (νᵀν − tr R̂_k)/tr(H P⁻ Hᵀ)),  P⁻ ← λ_k P⁻  (flag 5)
    4  S = H P⁻ Hᵀ + R̂_k = L_S L_Sᵀ ;  ν' = L_S ψ_c(L_S⁻¹ ν),  ψ_c(e) = clip(e, −c, c)   (flag 1)
    5  K = P⁻ Hᵀ S⁻¹ ;  x⁺ = x⁻ + K ν' ;  P⁺ = Joseph(P⁻, K, H, R̂_k)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from navlab.filters.base import (
    ACCEPTED,
    DOWNWEIGHTED,
    EPOCH_ANOMALY,
    Filter,
    KFLimit,
    Model,
    SideInfo,
    StepOut,
    Teaching,
    flag_fix,
    register,
)
from navlab.filters.kalman import measurement_prediction
from navlab.filters.sage_husa.kernels import (
    RState,
    forgetting_weight,
    rhat_bounds,
    sage_husa_R,
    sqrt_factor,
)
from navlab.linalg import (
    Array,
    batched,
    joseph_from_gain,
    kf_gain,
    mask_missing,
    mv,
    sym,
)
from navlab.params import param


@dataclass(frozen=True)
class RAKFParams:
    """RAKF options (ALGORITHMS.md §4.8, RECONSTRUCTION of Bai, Han, Qi 2012)."""

    b: float = param(0.98, lo=0.5, hi=1.0, tune=(0.8, 0.999), help="Sage–Husa forgetting factor b")
    adapt: bool = param(True, help="estimate R by Sage–Husa (off: R̂ stays R0)")
    gamma_s: float = param(
        3.0,
        lo=0.1,
        hi=1e12,
        tune=(1.0, 20.0),
        help="reserve coefficient γ_s of the divergence test νᵀν > γ_s·tr(S) (large = off)",
    )
    c: float = param(
        2.0,
        lo=0.1,
        hi=1e12,
        tune=(0.5, 10.0),
        help="Huber clip c of the whitened innovation L_S⁻¹ν (large = no clipping)",
    )


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
    kf_limit = KFLimit(
        {"adapt": False, "gamma_s": 1e12, "c": 1e12},
        why="R̂ fixed at R0, the divergence test and the clip switched off by huge thresholds",
    )
    teaching = Teaching(
        idea=(
            "An improved Sage–Husa filter (a reconstruction of Bai, Han, Qi 2012): Sage–Husa R̂, a "
            "divergence test that inflates P⁻ when the innovation is too large, and a Huber clip "
            "of the whitened innovation. Inflating P⁻ on an outlier makes it trust the bad "
            "measurement more, which is why it suffers from outliers."
        ),
        equations=(
            r"\hat R_k = (1 - d_k)\hat R_{k-1} + d_k(\nu\nu^\top - HP^-H^\top)",
            r"\nu^\top\nu > \gamma_s \operatorname{tr}(HP^-H^\top + \hat R_k) \Rightarrow "
            r"P^- \leftarrow \lambda_k P^-,\ \lambda_k = \max\!\left(1, "
            r"\dfrac{\nu^\top\nu - \operatorname{tr}\hat R_k}{\operatorname{tr}(HP^-H^\top)}\right)",
            r"S = L_S L_S^\top, \quad \nu' = L_S\,\psi_c(L_S^{-1}\nu), \quad "
            r"\psi_c(e) = \operatorname{clip}(e, -c, c)",
            r"K = P^- H^\top S^{-1}, \qquad x^+ = x^- + K\nu'",
        ),
    )

    def init(self, model: Model, x0: Array, P0: Array) -> RState:
        x0 = np.array(x0, dtype=float)
        B = x0.shape[0]
        P = batched(np.asarray(P0, dtype=float), B).copy()
        return RState(x0, P, batched(np.asarray(model.R0, dtype=float), B).copy(), 0)

    def update(self, model: Model, state: RState, k: int, z: Array, side: SideInfo):
        p = self.params
        B, m = z.shape
        x_m, P_m = state.x, state.P
        kk = state.k + 1
        flags = np.zeros((B, m), dtype=np.int8)
        mk = measurement_prediction(model, x_m, P_m, k, z)  # 1  ν = z − H x⁻
        ok, nu = mk.ok, mk.nu
        R = state.R
        if p.adapt:  # 2  Sage–Husa R̂_k with its guard
            lo, hi = rhat_bounds(model.R0)
            R, clamped = sage_husa_R(state.R, nu, mk.M, ok, forgetting_weight(kk, p.b), lo, hi)
            flag_fix(flags, clamped, overwrite=False)
        Rm = mask_missing(z, nu, R).R
        U, HPHt = mk.U, mk.M
        # 3  abnormality test and prior-covariance inflation (traces over the present channels)
        nn = np.einsum("bi,bi->b", nu, nu)  # νᵀν
        trHPH = np.trace(HPHt, axis1=-2, axis2=-1)
        trR = np.trace(Rm, axis1=-2, axis2=-1)  # tr R̂_k over the present channels: a missing
        if Rm is not R:  # channel's masked R_ii is exactly 1.0, taken out again
            trR = trR - np.count_nonzero(~ok, axis=-1)
        abnormal = nn > p.gamma_s * (trHPH + trR)
        lam = np.ones(B)
        if abnormal.any():  # (λ = 1 elsewhere: the products below are exact there)
            a = np.flatnonzero(abnormal)
            # a diverged run (P⁻ indefinite, so tr H P⁻ Hᵀ ≈ 0 or < 0, and λ P⁻ beyond the float
            # range) has no usable inflation: it becomes NaN here, silently (flag 9), and the
            # experiment records the divergence, instead of overflowing to ±inf (the quotient
            # itself may overflow there: that inf is caught by the test below)
            with np.errstate(over="ignore"):
                lam[a] = np.maximum(1.0, (nn[a] - trR[a]) / np.maximum(trHPH[a], 1e-300))
            maxP = np.maximum(np.abs(P_m[a]).max(axis=(-2, -1)), 1.0)
            broken = lam[a] > 1e300 / maxP
            lam[a[broken]] = np.nan
            flag_fix(flags, np.isnan(lam))
            P_m, U, HPHt = (A * lam[:, None, None] for A in (P_m, U, HPHt))  # P⁻ ← λ_k P⁻
        # 4  Huber clipping of the whitened innovation
        S = sym(HPHt + Rm)
        L, sfix = sqrt_factor(S)  # S = L_S L_Sᵀ
        flag_fix(flags, sfix, overwrite=False)
        e = np.linalg.solve(L, nu[..., None])[..., 0]  # e = L_S⁻¹ ν
        ae = np.abs(e)
        clip = (ae > p.c) & ok
        nu_c = mv(L, np.where(clip, p.c * np.sign(e), e))  # ν' = L_S ψ_c(e)
        # 5  update with the clipped innovation, Joseph form with R̂
        K, fixed = kf_gain(U, S)
        x = x_m + mv(K, nu_c)
        P = joseph_from_gain(P_m, K, U, S)
        flags[abnormal[:, None] & ok & (flags == ACCEPTED)] = EPOCH_ANOMALY
        flags[clip] = DOWNWEIGHTED
        flag_fix(flags, fixed, overwrite=False)
        out = StepOut(
            x=x,
            P=P,
            innov=nu,
            S=S,
            R_used=Rm,
            R_hat=R,
            weights=np.where(clip, p.c / np.where(clip, ae, 1.0), 1.0),
            flags=flags,
            stats={"lambda": lam},
        )
        return RState(x, P, R, kk), out
