"""Per-epoch weighted least squares (``wls``): the reference a user would try first.

No dynamics: every epoch is solved on its own by Gauss–Newton on the nominal model,

    x ← x + (Hᵀ R0⁻¹ H + Λ)⁻¹ (Hᵀ R0⁻¹ ν + Λ (x_prev − x)),   ν = z − h(x),

started from the previous epoch's solution. Λ = I/σ_prior² is a vague prior (σ_prior = 10 km by
default) that only keeps states the epoch does not observe (e.g. velocity from pseudoranges)
at their previous value; for observed states its influence is ~1e-8 relative. The reported P is
the inverse normal matrix. With ``huber_k`` > 0 the residuals are Huber-reweighted (iteratively
reweighted least squares from the third iteration on; Huber 1964), the usual robust variant.
Works on any model (linear or not); with a position measurement it returns the measured position.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from navlab.filters.base import (
    ACCEPTED,
    DOWNWEIGHTED,
    Filter,
    KFState,
    Model,
    SideInfo,
    StepOut,
    Teaching,
    register,
)
from navlab.linalg import Array, mask_missing, mT, mv, sym
from navlab.params import param


@dataclass(frozen=True)
class WlsParams:
    iterations: int = param(5, lo=1, hi=50, help="Gauss–Newton iterations per epoch")
    sigma_prior: float = param(
        1e4, lo=1.0, hi=1e9, help="vague prior σ on every state (keeps unobserved states)"
    )
    huber_k: float = param(
        0.0,
        lo=0.0,
        hi=100.0,
        help="Huber threshold on |residual|/σ for iteratively reweighted LS (0: plain WLS)",
    )


@register
class WLS(Filter):
    """Per-epoch Gauss–Newton weighted least squares with a vague prior (no dynamics)."""

    key = "wls"
    label = "WLS (per epoch)"
    family = "baseline"
    spec_section = "—"
    summary = "Solves every epoch on its own by weighted least squares with the nominal R: no motion model."
    Params = WlsParams
    kf_limit = None  # no dynamics: no parameter makes it the KF
    teaching = Teaching(
        idea=(
            "Weighted least squares solves each epoch on its own, weighting the measurements by "
            "R⁻¹: no motion model, no memory. It is the reference a filter must beat and a quick "
            "sanity check on real data."
        ),
        equations=(
            r"\nu = z_k - h(x), \qquad \Lambda = I/\sigma^2_{\mathrm{prior}}",
            r"x \leftarrow x + (H^\top R_0^{-1} H + \Lambda)^{-1}\left(H^\top R_0^{-1}\nu "
            r"+ \Lambda (x_{\mathrm{prev}} - x)\right)\quad(\text{iterated})",
            r"P_k = (H^\top R_0^{-1} H + \Lambda)^{-1}\qquad"
            r"\text{(no dynamics: each epoch stands alone)}",
        ),
        caveat="WLS has no dynamics: each step is the measurement alone (the prior is vague).",
    )

    def predict(self, model: Model, state: KFState, k: int) -> KFState:
        return state  # no dynamics

    def update(self, model: Model, state: KFState, k: int, z: Array, side: SideInfo):
        p = self.params
        x_prev = np.array(state.x, dtype=float)
        n = x_prev.shape[1]
        lam = np.eye(n) / p.sigma_prior**2
        x = x_prev.copy()
        Rinv = np.linalg.inv(model.R0)
        N = None
        sd = np.sqrt(np.diagonal(model.R0))
        weights = np.ones(z.shape)
        for it in range(p.iterations):
            H = model.H(x, k)
            nu = z - model.h(x, k)
            mk = mask_missing(z, nu, model.R0, H=H)
            ok, nu, R, H = mk.ok, mk.nu, mk.R, mk.H
            Ri = Rinv if ok.all() else np.linalg.inv(R) * (ok[:, :, None] & ok[:, None, :])
            if p.huber_k > 0 and it >= 2:  # IRLS once the geometry has converged
                u = np.abs(nu) / sd
                weights = np.where(u <= p.huber_k, 1.0, p.huber_k / np.maximum(u, 1e-12))
                w = np.sqrt(weights)
                Ri = w[:, :, None] * Ri * w[:, None, :]
            HtRi = mT(H) @ Ri
            N = HtRi @ H + lam
            rhs = mv(HtRi, nu) + mv(lam, x_prev - x)
            x = x + np.linalg.solve(N, rhs[..., None])[..., 0]
        H = model.H(x, k)
        nu = z - model.h(x, k)
        mk = mask_missing(z, nu, model.R0, H=H)
        ok, nu, R, H = mk.ok, mk.nu, mk.R, mk.H
        P = sym(np.linalg.inv(N))
        S = sym(H @ P @ mT(H) + R)
        flags = np.where((weights < 1.0) & ok, DOWNWEIGHTED, ACCEPTED).astype(np.int8)
        out = StepOut(x=x, P=P, innov=nu, S=S, R_used=R, weights=np.where(ok, weights, 1.0), flags=flags)
        return KFState(x, P), out
