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

from navlab.filters.base import R_HAT_AT_BAND, KFLimit, Model, Teaching, band_param, register
from navlab.filters.kalman import Noise, Prior
from navlab.filters.sage_husa.kernels import FadingMemory, RState
from navlab.jit import Kernel, RunStep
from navlab.linalg import CHOLESKY_LOWER, Array, cholesky_lower, mask_missing
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
    r_min: float = band_param("r_min")
    r_max: float = band_param("r_max")


@register
class RAKF(FadingMemory):
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

    def noise(self, model: Model, state: RState, pr: Prior, z: Array) -> Noise:
        """2–4  Sage–Husa R̂, P⁻ inflated on an abnormal epoch, the clipped innovation (5: KF update)."""
        mk = pr.mk
        R, clamped, _ = self.sage_husa(model, state, pr, mk.ok)  # 2  Sage–Husa R̂_k with its guard
        Rm = mask_missing(z, mk.nu, R).R
        lam, nu_c, w, flags = RAKF_STEP((pr.P, mk.nu, mk.M, mk.ok, Rm), (self.params.gamma_s, self.params.c))
        flags[clamped & (flags == 0)] = R_HAT_AT_BAND  # R̂ held at its band where no other code stands
        if not np.all(lam == 1.0):  # 3  P⁻ ← λ_k P⁻ (and with it U = P⁻Hᵀ, M = H P⁻ Hᵀ)
            s = lam[:, None, None]
            pr = pr._replace(P=pr.P * s, mk=mk._replace(U=mk.U * s, M=mk.M * s))
        return Noise(Rm, R_hat=R, weights=w, flags=flags, stats={"lambda": lam}, nu=nu_c, prior=pr)


def rakf_step(P, nu, M, ok, R, gamma_s, c):  # pragma: no cover - compiled by numba
    """§4.8 steps 3–4 for ONE run: the inflation λ_k of P⁻ and the clipped innovation ν'.

    P = P⁻, nu = ν, M = H P⁻ Hᵀ and R = R̂_k with missing channels masked (ok False). Returns λ_k
    (NaN: a diverged run, every flag 9), ν', the clip weights c/|e_i| and the flags (9 S repaired,
    5 abnormal epoch, 1 clipped).
    """
    m = nu.shape[0]
    nn, trM, trR = 0.0, 0.0, 0.0
    for i in range(m):
        nn += nu[i] * nu[i]  # νᵀν
        trM += M[i, i]  # tr H P⁻ Hᵀ
        trR += R[i, i] if ok[i] else 0.0  # tr R̂_k over the present channels
    lam = 1.0
    abnormal = nn > gamma_s * (trM + trR)  # 3  νᵀν > γ_s tr(H P⁻ Hᵀ + R̂_k)
    if abnormal:
        q = (nn - trR) / max(trM, 1e-300)
        lam = q if not q <= 1.0 else 1.0  # λ_k = max(1, (νᵀν − tr R̂_k)/tr(H P⁻ Hᵀ)), NaN kept
        if not lam < 1e300 / max(np.abs(P).max(), 1.0):  # λ P⁻ beyond the float range: diverged
            lam = np.nan
    S = lam * M + R  # 4  S = H P⁻ Hᵀ + R̂_k = L_S L_Sᵀ
    S = 0.5 * (S + S.T)
    L, sfix = sqrt_factor(S)
    e = np.full(m, np.nan)  # a diverged run's e stays NaN
    if np.all(np.isfinite(L)) and np.all(np.isfinite(nu)):
        e = np.linalg.solve(L, nu)  # e = L_S⁻¹ ν
    w, flags = np.ones(m), np.zeros(m, dtype=np.int8)
    for i in range(m):
        if sfix:
            flags[i] = 9
        elif abnormal and ok[i]:
            flags[i] = 5
        if ok[i] and abs(e[i]) > c:  # ψ_c(e) = clip(e, −c, c)
            w[i] = c / abs(e[i])
            e[i] = c if e[i] > 0 else -c
            flags[i] = 1
    if lam != lam:
        flags[:] = 9
    return lam, L @ e, w, flags  # ν' = L_S ψ_c(L_S⁻¹ ν)


def sqrt_factor(S):  # pragma: no cover - compiled by numba
    """A square root L (L Lᵀ = S) of ONE S: its Cholesky factor; where S is not numerically positive
    definite (a diverging P), the eigen-factor V·diag(√max(w, ε)), marked (flag 9).
    """
    L = np.zeros(S.shape)
    if cholesky_lower(S, L):
        return L, False
    if not np.all(np.isfinite(S)):
        return np.full(S.shape, np.nan), True
    w, V = np.linalg.eigh(S)
    eps = 1e-12 * max(np.abs(w).max(), 1e-300)
    return V * np.sqrt(np.maximum(w, eps)), True


SQRT_FACTOR = Kernel(sqrt_factor, uses=(CHOLESKY_LOWER,))
RAKF_STEP = RunStep(
    rakf_step, n_runs=5, outs=((None, float), (1, float), (1, float), (1, np.int8)), uses=(SQRT_FACTOR,)
)
