"""Plain references of the KF, the oracle KF, the χ²-gated KF (§1.1, §1.4, §1.5) and the EKF (§1.2)."""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from navlab.filters.reference import Trace, plain, reference


def _kf(model, x, P, z, sides, p, *, oracle: bool = False, gate: bool = False, ekf: bool = False):
    xs, Ps, flags = [], [], []
    K = z.shape[0] - 1
    m = z.shape[1]
    for k in range(1, K + 1):
        x, P = plain.kf_predict(model, x, P, k, jacobian_at_x=ekf)  # 1–2
        zk, R = z[k], np.asarray(model.R0, dtype=float)
        if oracle:  # §1.4: P⁻ + Q_extra, z' = z − b_true, R_used = R_true
            if sides[k].Q_extra is not None:
                P = P + sides[k].Q_extra
            zk, R = zk - sides[k].bias, np.diag(sides[k].R_true)
        o = plain.present(zk)
        fl = np.zeros(m, dtype=np.int8)
        if o.size:
            Hk = plain.H(model, x, k)[o]
            nu = zk[o] - plain.h(model, x, k)[o]  # 3  ν = z − h(x⁻)
            Ro = R[np.ix_(o, o)]
            S = Hk @ P @ Hk.T + Ro
            if gate and nu @ np.linalg.solve(S, nu) > chi2.ppf(1.0 - p.alpha, o.size):
                fl[o] = 2  # §1.5 step 4: the epoch is rejected, x⁺ = x⁻, P⁺ = P⁻
            else:
                x, P, _ = plain.kf_step(x, P, nu, Hk, Ro)  # 3–6
        xs.append(x)
        Ps.append(P)
        flags.append(fl)
    return Trace(np.array(xs), np.array(Ps), flags=np.array(flags))


@reference("kf")
def kf(model, x0, P0, z, sides, p) -> Trace:
    """§1.1: x⁻ = F x⁺, P⁻ = F P⁺ Fᵀ + Q; ν, S = H P⁻ Hᵀ + R0, K = P⁻ Hᵀ S⁻¹, x⁺, Joseph P⁺."""
    return _kf(model, x0, P0, z, sides, p)


@reference("oracle-kf", note="mode 'exact' only")
def oracle_kf(model, x0, P0, z, sides, p) -> Trace:
    """§1.4: the KF with Q + Q_extra, the known outlier mean removed and the true R."""
    if p.mode != "exact":
        raise NotImplementedError("the reference implements mode='exact'")
    return _kf(model, x0, P0, z, sides, p, oracle=True)


@reference("chi2-kf", note="the epoch gate only (not per_channel)")
def chi2_kf(model, x0, P0, z, sides, p) -> Trace:
    """§1.5: the KF, except that an epoch with γ = νᵀS⁻¹ν > χ²_{1−α}(m) keeps its prediction."""
    if p.per_channel:
        raise NotImplementedError("the reference implements the epoch gate")
    return _kf(model, x0, P0, z, sides, p, gate=True)


@reference("ekf")
def ekf(model, x0, P0, z, sides, p) -> Trace:
    """§1.2: x⁻ = f(x⁺), A = ∂f/∂x at x⁺, P⁻ = A P⁺ Aᵀ + Q; H = ∂h/∂x at x⁻; the KF update."""
    return _kf(model, x0, P0, z, sides, p, ekf=True)
