"""The fading-memory KF: the KF whose prior covariance is inflated by α² each step (old data fade)."""

from dataclasses import dataclass

import numpy as np

from navlab.filters import Filter, KFState, StepOut, register
from navlab.filters.base import KFLimit
from navlab.params import param


@dataclass(frozen=True)
class FadingParams:
    alpha: float = param(1.02, lo=1.0, hi=2.0, help="fading factor α: P⁻ = α² F P Fᵀ + Q")


@register
class FadingKF(Filter):
    key, label, family = "fading-kf", "Fading-memory KF", "baseline"
    summary = "The KF with P⁻ = α² F P Fᵀ + Q: a fixed inflation that trusts recent data more."
    paper = "H. W. Sorenson, J. E. Sacks, Inform. Sci. 3 (1971)"
    Params = FadingParams
    kf_limit = KFLimit({"alpha": 1.0}, why="α = 1 does not fade: the KF's prediction")

    def predict(self, model, state, k):
        F = model.F(k)
        P = self.params.alpha**2 * F @ state.P @ np.swapaxes(F, -1, -2) + model.Q(k)
        return KFState(model.f(state.x, k), P)

    def update(self, model, state, k, z, side):
        x, P = state
        ok = np.isfinite(z)  # (B, m); NaN = channel missing: zero row of H, unit decoupled R
        H = np.broadcast_to(model.H(x, k), (*z.shape, x.shape[1])) * ok[..., None]
        nu = np.where(ok, z - model.h(x, k), 0.0)
        R = np.where(ok[:, :, None] & ok[:, None, :], model.R0, 0.0) + np.eye(z.shape[1]) * ~ok[:, None]
        S = H @ P @ H.mT + R
        K = P @ H.mT @ np.linalg.inv(S)
        I_KH = np.eye(x.shape[1]) - K @ H
        P = I_KH @ P @ I_KH.mT + K @ R @ K.mT  # Joseph form
        x = x + (K @ nu[..., None])[..., 0]
        return KFState(x, P), StepOut(x=x, P=0.5 * (P + P.mT), innov=nu, S=S, R_used=model.R0)
