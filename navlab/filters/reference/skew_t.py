"""Plain reference of the skew-t VB KF (§11) for one run.

The fast filter (:mod:`navlab.filters.skew_t`) gets each channel's leave-one-out prediction from
the identities d_j = ν'_j − (S⁻¹ν')_j/(S⁻¹)_jj, v_j = 1/(S⁻¹)_jj − R'_j, and the truncated moments
from its own closed form. Here, instead, for every channel j:

* channel j is DELETED and the prior is updated again with the other channels' pseudo-measurements
  (a KF step in state space): the cavity x_c, P_c, so d_j = H_j (x_c − x⁻), v_j = H_j P_c H_jᵀ;
* the Gaussian joint of (g, u_j) — g = H_j (x − x⁻) ~ N(d_j, v_j), u_j ~ N(0, 1/λ_j) — is
  conditioned on ν_j = g + Δ_j u_j + ε_j, ε_j ~ N(0, R_j/λ_j), in covariance form;
* its u-marginal is truncated to u ≥ 0 with :func:`scipy.stats.truncnorm` (E, V); the site is
  (1/V − 1/C_uu, E/V − m_u/C_uu); E[(ν_j − g − Δ_j u_j)²] follows from g | u (linear in u);
* λ_j = (ν + 2)/(ν + ψ_j) on a skewed channel, (ν + 1)/(ν + ψ_j) elsewhere.

All sites and λ's are updated from the same previous iterate (parallel), as in the fast filter.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import truncnorm

from navlab.filters.reference import Trace, plain, reference


def _tilted(nu, d, v, r_lam, lam, Delta):
    """Moments of channel j's tilted distribution: E[u], V[u], E[e²] (e = ν − g − Δ u), cavity (m_u, C_uu)."""
    Sig = np.diag([v, 1.0 / lam])  # (g, u) before channel j's likelihood
    b = np.array([1.0, Delta])  # ν_j = bᵀ (g, u) + ε
    c = Sig @ b
    s = b @ c + r_lam
    m = np.array([d, 0.0]) + c * (nu - d) / s  # conditioned on ν_j (covariance form)
    C = Sig - np.outer(c, c) / s
    if Delta == 0.0:  # no u: e = ν − g
        return 0.0, 0.0, (nu - m[0]) ** 2 + C[0, 0], m[1], C[1, 1]
    sd = np.sqrt(C[1, 1])
    tn = truncnorm(-m[1] / sd, np.inf, loc=m[1], scale=sd)  # u ≥ 0
    Eu, Vu = float(tn.mean()), float(tn.var())
    slope = C[0, 1] / C[1, 1]  # g | u = m_g + slope (u − m_u) + N(0, C_gg − C_gu²/C_uu)
    Ee = nu - m[0] - slope * (Eu - m[1]) - Delta * Eu
    Ve = (slope + Delta) ** 2 * Vu + C[0, 0] - C[0, 1] ** 2 / C[1, 1]
    return Eu, Vu, Ee * Ee + Ve, m[1], C[1, 1]


@reference("skew-t-kf")
def skew_t_kf(model, x0, P0, z, sides, p) -> Trace:
    """§11: N parallel VB + EP iterations from the prior, then the KF update with (ν′, R′)."""
    x, P = np.array(x0, float), np.array(P0, float)
    r_all = p.r_scale * np.diag(np.asarray(model.R0, dtype=float))
    skew_all = getattr(model, "positive_skew", None)
    skew_all = np.zeros(r_all.size, bool) if skew_all is None else np.asarray(skew_all, bool)
    xs, Ps, ws, fls = [], [], [], []
    for k in range(1, z.shape[0]):
        x_m, P_m = plain.kf_predict(model, x, P, k, jacobian_at_x=True)
        x, P = x_m, P_m
        o = plain.present(z[k])
        w = np.ones(r_all.size)
        fl = np.zeros(r_all.size, dtype=np.int8)
        if o.size:
            Hk = plain.H(model, x_m, k)[o]
            nu = z[k, o] - plain.h(model, x_m, k)[o]
            r = r_all[o]
            Delta = np.where(skew_all[o], p.delta * np.sqrt(r), 0.0)
            m = o.size
            lam, pi, kappa = np.ones(m), np.zeros(m), np.zeros(m)
            for _ in range(p.iters):
                tau = 1.0 / (lam + pi)
                nu_p = nu - Delta * kappa * tau  # ν′ = ν − Δ μ̃
                R_p = r / lam + Delta**2 * tau  # R′ = R/λ + Δ² τ̃
                lam_new, pi_new, kappa_new = lam.copy(), pi.copy(), kappa.copy()
                for j in range(m):
                    oth = [i for i in range(m) if i != j]
                    xc, Pc = x_m, P_m
                    if oth:  # channel j deleted, the others updated again
                        xc, Pc, _ = plain.kf_step(x_m, P_m, nu_p[oth], Hk[oth], np.diag(R_p[oth]))
                    d = Hk[j] @ (xc - x_m)
                    v = Hk[j] @ Pc @ Hk[j]
                    Eu, Vu, Ee2, m_u, C_uu = _tilted(nu[j], d, v, r[j] / lam[j], lam[j], Delta[j])
                    if Delta[j] > 0.0:
                        pi_new[j] = 1.0 / Vu - 1.0 / C_uu
                        kappa_new[j] = Eu / Vu - m_u / C_uu
                        lam_new[j] = (p.dof + 2.0) / (p.dof + Ee2 / r[j] + Eu * Eu + Vu)
                    else:
                        lam_new[j] = (p.dof + 1.0) / (p.dof + Ee2 / r[j])
                lam, pi, kappa = lam_new, pi_new, kappa_new
            tau = 1.0 / (lam + pi)
            nu_p = nu - Delta * kappa * tau
            R_p = r / lam + Delta**2 * tau
            x, P, _ = plain.kf_step(x_m, P_m, nu_p, Hk, np.diag(R_p))
            w[o] = r / R_p
            fl[o] = w[o] < p.flag_below
        xs.append(x)
        Ps.append(P)
        ws.append(w)
        fls.append(fl)
    return Trace(np.array(xs), np.array(Ps), weights=np.array(ws), flags=np.array(fls))
