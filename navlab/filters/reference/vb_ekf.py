"""Plain reference of the VB-EKF (§7; Hou et al. 2024 Algorithm 1 = Huang et al. 2018) for one run,
as printed: inverse matrices, E[R⁻¹] = (u − m − 1) U⁻¹ and R̂ = {E[R⁻¹]}⁻¹ (Huang's convention).
"""

from __future__ import annotations

import numpy as np

from navlab.filters.reference import Trace, plain, reference


@reference("vb-ekf", missing=False, note="every channel present; tol = 0, adapt_P")
def vb_ekf(model, x0, P0, z, sides, p) -> Trace:
    """§7 steps 1–4."""
    if p.tol != 0 or not p.adapt_P:
        raise NotImplementedError("the reference implements N iterations with P adaptation")
    x, P = np.array(x0, float), np.array(P0, float)
    n, m = x.size, z.shape[1]
    u, U = m + 1 + p.tau_R, p.tau_R * np.asarray(model.R0, dtype=float)  # û₀, Û₀
    xs, Ps, Rs = [], [], []
    for k in range(1, z.shape[0]):
        if not np.isfinite(z[k]).all():
            raise NotImplementedError("the reference needs every channel present")
        x_pred, P_pred = plain.kf_predict(model, x, P, k, jacobian_at_x=True)  # 1
        x_i, P_i = x_pred.copy(), P_pred.copy()  # 2
        t_pred, T_pred = n + p.tau_P + 1, p.tau_P * P_pred
        u_pred, U_pred = p.rho * (u - m - 1) + m + 1, p.rho * U  # (S3 eq. 14)
        Hk = plain.H(model, x_pred, k)
        for _ in range(p.iterations):  # 3
            T_new = T_pred + P_i + np.outer(x_i - x_pred, x_i - x_pred)  # P-part
            t_new = t_pred + 1
            res = z[k] - plain.h(model, x_i, k)  # R-part
            U_new = U_pred + np.outer(res, res) + Hk @ P_i @ Hk.T
            u_new = u_pred + 1
            R_hat = np.linalg.inv((u_new - m - 1) * np.linalg.inv(U_new))
            P_hat = np.linalg.inv((t_new - n - 1) * np.linalg.inv(T_new))
            K = P_hat @ Hk.T @ np.linalg.inv(Hk @ P_hat @ Hk.T + R_hat)
            x_i = x_pred + K @ (z[k] - plain.h(model, x_pred, k))
            P_i = P_hat - K @ Hk @ P_hat
        x, P, u, U = x_i, P_i, u_new, U_new  # 4
        xs.append(x)
        Ps.append(P)
        Rs.append(R_hat)
    return Trace(np.array(xs), np.array(Ps), np.array(Rs))
