"""Plain references of the Huber KF (§2), the VB adaptive KF and HAKF (§3, S0 eqs. 11–21) and the
Student-t VB KF (§1.6): state-space transcriptions for one run (a K, x, P per iteration).
"""

from __future__ import annotations

import numpy as np

from navlab.filters.reference import Trace, plain, reference


def _huber_w(e, gamma):
    """S0 eqs. 8–9: w = 1 where |e| < γ, γ/|e| otherwise."""
    return np.array([1.0 if abs(v) < gamma else gamma / abs(v) for v in e])


@reference("huber-kf", note="normalize='R', one pass (no IRLS)")
def huber_kf(model, x0, P0, z, sides, p) -> Trace:
    """§2: e = L⁻¹ ν (R0 = L Lᵀ), Ψ = diag(w(e)), R̃ = L Ψ⁻¹ Lᵀ, the KF update with R̃."""
    if p.normalize != "R" or p.irls_iters != 1:
        raise NotImplementedError("the reference implements normalize='R' with one pass")
    x, P = np.array(x0, float), np.array(P0, float)
    R0 = np.asarray(model.R0, dtype=float)
    xs, Ps, ws, fls = [], [], [], []
    for k in range(1, z.shape[0]):
        x, P = plain.kf_predict(model, x, P, k)
        o = plain.present(z[k])
        w = np.ones(z.shape[1])
        if o.size:
            Hk = plain.H(model, x, k)[o]
            nu = z[k, o] - plain.h(model, x, k)[o]
            L = np.linalg.cholesky(R0[np.ix_(o, o)])
            e = np.linalg.solve(L, nu)  # (16) e = R^{-1/2} ν
            w[o] = _huber_w(e, p.gamma)  # (9)
            Rt = L @ np.diag(1.0 / w[o]) @ L.T  # (10) R̃ = L Ψ⁻¹ Lᵀ
            x, P, _ = plain.kf_step(x, P, nu, Hk, Rt)
        xs.append(x)
        Ps.append(P)
        ws.append(w)
        fls.append((w < 1.0).astype(np.int8))
    return Trace(np.array(xs), np.array(Ps), weights=np.array(ws), flags=np.array(fls))


def _vb(model, x0, P0, z, p, huber: bool) -> Trace:
    """S0 eqs. 11–21: forgetting, then N fixed-point iterations, each from the prior."""
    x, P = np.array(x0, float), np.array(P0, float)
    r0 = np.diag(np.asarray(model.R0, dtype=float))
    alpha = np.full(r0.size, float(p.alpha0))
    beta = alpha * r0
    xs, Ps, Rs, ws, fls = [], [], [], [], []
    for k in range(1, z.shape[0]):
        x_m, P_m = plain.kf_predict(model, x, P, k)  # (11)–(12)
        if p.adapt:
            alpha, beta = p.rho * alpha, p.rho * beta  # (13)–(14)
        o = plain.present(z[k])
        if p.adapt:
            alpha = alpha.copy()
            alpha[o] += 0.5  # α = α⁻ + 1/2 on the observed channels
        beta_m = beta.copy()
        x, P = x_m, P_m
        w = np.ones(r0.size)
        if o.size:
            Hk = plain.H(model, x_m, k)[o]
            nu = z[k, o] - plain.h(model, x_m, k)[o]
            r = nu
            for it in range(p.iters):
                Rhat = beta[o] / alpha[o]  # (15)
                if huber:
                    e = (r if (p.irls and it > 0) else nu) / np.sqrt(Rhat)  # (16)
                    w[o] = _huber_w(e, p.gamma)  # (9)
                Rt = Rhat / w[o]  # (17)
                K = P_m @ Hk.T @ np.linalg.inv(Hk @ P_m @ Hk.T + np.diag(Rt))  # (18)
                x = x_m + K @ nu  # (19)
                P = (np.eye(x.size) - K @ Hk) @ P_m  # (20)
                if not p.adapt:
                    break
                r = nu - Hk @ (x - x_m)  # z − H x^(it+1)
                r2 = r * r
                if huber and p.robust_beta:
                    r2 = r2 * _huber_w(r / np.sqrt(Rhat), p.gamma)
                b_new = beta_m.copy()
                b_new[o] = beta_m[o] + 0.5 * r2 + 0.5 * np.diag(Hk @ P @ Hk.T)  # (21)
                delta = np.max(np.abs(b_new - beta) / beta)
                beta = b_new
                if p.tol > 0 and delta < p.tol:  # this run has converged
                    break
        xs.append(x)
        Ps.append(P)
        Rs.append(np.diag(beta / alpha))
        ws.append(w.copy())
        fls.append((w < 1.0).astype(np.int8))
    return Trace(np.array(xs), np.array(Ps), np.array(Rs), np.array(ws), np.array(fls))


@reference("vb-akf")
def vb_akf(model, x0, P0, z, sides, p) -> Trace:
    """§3.1 (Särkkä & Nummenmaa 2009): the VB adaptive KF."""
    return _vb(model, x0, P0, z, p, huber=False)


@reference("hakf")
def hakf(model, x0, P0, z, sides, p) -> Trace:
    """§3.2 (Zuo et al. 2017): the VB adaptive KF with Huber weights inside the iterations."""
    return _vb(model, x0, P0, z, p, huber=True)


@reference("student-t-kf")
def student_t_kf(model, x0, P0, z, sides, p) -> Trace:
    """§1.6: N_t times a KF update from the prior with R0/λ̄, λ̄ = (ν_t + m)/(ν_t + tr(D R0⁻¹))."""
    x, P = np.array(x0, float), np.array(P0, float)
    R0 = np.asarray(model.R0, dtype=float)
    xs, Ps, ws, fls = [], [], [], []
    for k in range(1, z.shape[0]):
        x_m, P_m = plain.kf_predict(model, x, P, k)
        x, P = x_m, P_m
        o = plain.present(z[k])
        lam = 1.0
        if o.size:
            Hk = plain.H(model, x_m, k)[o]
            nu = z[k, o] - plain.h(model, x_m, k)[o]
            Ro = R0[np.ix_(o, o)]
            for _ in range(p.iters):
                x, P, _ = plain.kf_step(x_m, P_m, nu, Hk, Ro / lam)
                r = nu - Hk @ (x - x_m)
                D = np.outer(r, r) + Hk @ P @ Hk.T
                lam = (p.dof + o.size) / (p.dof + np.trace(D @ np.linalg.inv(Ro)))
            x, P, _ = plain.kf_step(x_m, P_m, nu, Hk, Ro / lam)
        w = np.ones(z.shape[1])
        w[o] = lam
        fl = np.zeros(z.shape[1], dtype=np.int8)
        fl[o] = lam < p.flag_below
        xs.append(x)
        Ps.append(P)
        ws.append(w)
        fls.append(fl)
    return Trace(np.array(xs), np.array(Ps), weights=np.array(ws), flags=np.array(fls))
