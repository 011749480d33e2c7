"""Baseline Kalman filters: the standard KF, the oracle KF and the χ²-gated KF.

These also work on nonlinear models (they then are the EKF update: h(x⁻) and its Jacobian).

References
----------
R. E. Kalman, "A new approach to linear filtering and prediction problems", J. Basic Eng. 82, 1960.
Y. Bar-Shalom, X. R. Li, T. Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, Wiley 2001 (ch. 5: consistency; NIS gating).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from navlab.filters.base import (
    NUMERICAL_FIX,
    REJECTED,
    Filter,
    KFState,
    Model,
    SideInfo,
    StepOut,
    register,
)
from navlab.linalg import (
    Array,
    PHt,
    chi2_threshold,
    diag,
    joseph_from_gain,
    kf_gain,
    mask_missing,
    mv,
    quad,
    sym,
)
from navlab.params import param


def kf_update(
    model: Model, x: Array, P: Array, k: int, z: Array, R: Array
) -> tuple[Array, Array, Array, Array, Array, Array]:
    """One Kalman (EKF) measurement update with covariance R, missing channels dropped.

    Implements ALGORITHMS.md §1.1 steps 3–6::

        ν = z − h(x⁻) ;  S = H P⁻ Hᵀ + R ;  K = P⁻ Hᵀ S⁻¹ ;  x⁺ = x⁻ + K ν ;  P⁺ = Joseph

    Returns
    -------
    x, P : posterior.
    nu, S, R : innovation, its covariance and the R actually used (masked).
    flags : (B, m) int8 (9 where S needed a numerical fix).
    """
    H = model.H(x, k)
    nu = z - model.h(x, k)
    _ok, nu, H, R = mask_missing(z, nu, H, R)
    U, HU = PHt(P, H)
    S = sym(HU + R)
    K, fixed = kf_gain(U, S)
    x = x + mv(K, nu)
    P = joseph_from_gain(P, K, U, S)  # = (I−KH)P(I−KH)ᵀ + KRKᵀ, from U = PHᵀ and S
    flags = np.zeros(z.shape, dtype=np.int8)
    if np.any(fixed):
        flags[np.broadcast_to(fixed, z.shape[:1])] = NUMERICAL_FIX
    return x, P, nu, S, R, flags


@register
class KF(Filter):
    """Standard Kalman filter with the nominal Q and R, Joseph-form update (ALGORITHMS.md §1.1)."""

    key = "kf"
    label = "KF"
    family = "baseline"
    spec_section = "§1.1"
    summary = "The optimal linear-Gaussian filter with fixed, assumed-known Q and R: the reference."

    def update(self, model: Model, state: KFState, k: int, z: Array, side: SideInfo):
        x, P, nu, S, R, flags = kf_update(model, state.x, state.P, k, z, model.R0)
        return KFState(x, P), StepOut(x=x, P=P, innov=nu, S=S, R_used=R, flags=flags)


@dataclass(frozen=True)
class OracleParams:
    """Oracle KF options."""

    mode: str = param(
        "exact",
        choices=("exact", "skip"),
        help="exact: true R(t), known outlier mean removed (MMSE floor); skip: ignore outlier epochs",
    )


@register
class OracleKF(Filter):
    """The KF that knows the true R(t), the outlier epochs and means, and any Q anomaly (§1.4).

    It is the exact MMSE filter of the simulated model: the floor every robust or adaptive filter
    is judged against. ``mode="skip"`` instead drops contaminated channels; it is NOT a floor for
    zero-mean outliers (they still carry information).
    """

    key = "oracle-kf"
    label = "Oracle KF"
    family = "oracle"
    spec_section = "§1.4"
    summary = "Knows the true noise: the accuracy floor (needs simulator ground truth)."
    estimates_R = True  # it reports the true R as its "estimate", so plots show the truth
    Params = OracleParams

    def update(self, model: Model, state: KFState, k: int, z: Array, side: SideInfo):
        R_true = side.R_true
        P_prior = state.P if side.Q_extra is None else state.P + side.Q_extra  # (§1.4 step 1)
        z = np.where(side.outlier, np.nan, z) if self.params.mode == "skip" else z - side.bias
        R = R_true[..., :, None] * np.eye(z.shape[-1])
        x, P, nu, S, R, flags = kf_update(model, state.x, P_prior, k, z, R)
        return KFState(x, P), StepOut(x=x, P=P, innov=nu, S=S, R_used=R, R_hat=R, flags=flags)


@dataclass(frozen=True)
class Chi2Params:
    """χ²-gated KF options (ALGORITHMS.md §1.5)."""

    alpha: float = param(0.01, lo=1e-6, hi=0.5, help="false-alarm probability of the NIS gate")
    per_channel: bool = param(
        False, help="gate each channel on |ν_i|/√S_ii > c_gate instead of the whole epoch"
    )
    c_gate: float = param(3.0, lo=0.5, hi=100.0, help="per-channel gate in innovation sigmas")


@register
class Chi2KF(Filter):
    """KF that skips measurements whose NIS exceeds the χ² gate (ALGORITHMS.md §1.5)."""

    key = "chi2-kf"
    label = "χ²-gated KF"
    family = "robust"
    spec_section = "§1.5"
    summary = "Rejects an epoch whose normalised innovation squared fails a χ² test."
    Params = Chi2Params

    def update(self, model: Model, state: KFState, k: int, z: Array, side: SideInfo):
        p = self.params
        x0, P0 = state.x, state.P
        H = model.H(x0, k)
        nu = z - model.h(x0, k)
        ok, nu, H, R = mask_missing(z, nu, H, model.R0)
        U, HU = PHt(P0, H)
        S = sym(HU + R)
        K, fixed = kf_gain(U, S)
        flags = np.zeros(z.shape, dtype=np.int8)
        nis = quad(nu, S)
        if p.per_channel:
            reject = (np.abs(nu) > p.c_gate * np.sqrt(diag(S))) & ok
            K = np.broadcast_to(K, (*z.shape[:1], *K.shape[-2:])) * ~reject[:, None, :]
            flags[reject] = REJECTED
            x = x0 + mv(K, nu)
            P = joseph_from_gain(P0, K, U, S)
            weights = (~reject).astype(float)
        else:
            dof = ok.sum(axis=1)
            thr = chi2_threshold(p.alpha, dof, z.shape[-1])
            reject = (nis > thr) & (dof > 0)
            x1 = x0 + mv(K, nu)
            P1 = joseph_from_gain(P0, K, U, S)
            x = np.where(reject[:, None], x0, x1)
            P = np.where(reject[:, None, None], P0, P1) if reject.any() else P1
            flags[reject[:, None] & ok] = REJECTED
            weights = np.where(reject[:, None], 0.0, 1.0) * np.ones(z.shape)
        if np.any(fixed):
            flags[np.broadcast_to(fixed, z.shape[:1])] = NUMERICAL_FIX
        out = StepOut(x=x, P=P, innov=nu, S=S, R_used=R, weights=weights, flags=flags, stats={"nis": nis})
        return KFState(x, P), out
