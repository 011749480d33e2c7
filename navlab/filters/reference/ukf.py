"""Plain references of the SVD-UKF (§1.3) and the multiple-fading-factor MFUKF (§5): explicit
sigma points from ``numpy.linalg.svd`` for one run (no closed forms for linear models).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from navlab.filters.reference import Trace, plain, reference


def _weights(n, p):
    lam = p.alpha_ut**2 * (n + p.kappa) - n
    Wm = np.full(2 * n + 1, 0.5 / (n + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = lam / (n + lam) + (1.0 - p.alpha_ut**2 + p.beta_ut)
    return Wm, Wc, np.sqrt(n + lam)


def _sigma(x, P, c):
    """§1.3 a–c: P_s = (P + Pᵀ)/2 = U Σ_s Tᵀ, L = U Σ_s^{1/2}, χ = [x, x + c L_j, x − c L_j]."""
    U, s, _ = np.linalg.svd(0.5 * (P + P.T))
    L = U * np.sqrt(s)
    return np.vstack([x, x + c * L.T, x - c * L.T])


def _ut(Y, Wm, Wc):
    mean = Wm @ Y
    d = Y - mean
    return mean, (d * Wc[:, None]).T @ d, d


def _predict(model, x, P, k, p):
    """§1.3 steps 1–2."""
    Wm, Wc, c = _weights(x.size, p)
    chi = _sigma(x, P, c)
    Yf = np.array([plain.f(model, ci, k) for ci in chi])
    x_m, P_m, _ = _ut(Yf, Wm, Wc)
    return x_m, P_m + plain.Q(model, k), Yf


def _measure(model, x, P, k, p, o):
    """§1.3 steps 3–6 (sigma points redrawn from (x⁻, P⁻)) for the channels o."""
    Wm, Wc, c = _weights(x.size, p)
    chi = _sigma(x, P, c)
    Y = np.array([plain.h(model, ci, k)[o] for ci in chi])
    z_hat, A, dY = _ut(Y, Wm, Wc)
    Pxy = ((chi - x) * Wc[:, None]).T @ dY
    return z_hat, A, Pxy


def _check(p):
    if p.resample != "redraw" or p.sqrt_method != "svd":
        raise NotImplementedError("the reference implements redrawn SVD sigma points")


@reference("svd-ukf", note="redrawn SVD sigma points (the defaults)")
def svd_ukf(model, x0, P0, z, sides, p) -> Trace:
    """§1.3 steps 1–8: K = Pxy Pyy⁻¹, x⁺ = x⁻ + K V, P⁺ = P⁻ − K Pyy Kᵀ."""
    _check(p)
    x, P = np.array(x0, float), np.array(P0, float)
    R0 = np.asarray(model.R0, dtype=float)
    xs, Ps = [], []
    for k in range(1, z.shape[0]):
        x, P, _ = _predict(model, x, P, k, p)
        o = plain.present(z[k])
        if o.size:
            z_hat, A, Pxy = _measure(model, x, P, k, p, o)
            Pyy = A + R0[np.ix_(o, o)]
            K = Pxy @ np.linalg.inv(Pyy)
            x = x + K @ (z[k, o] - z_hat)
            P = P - K @ Pyy @ K.T
        xs.append(x)
        Ps.append(P)
    return Trace(np.array(xs), np.array(Ps))


@reference("mfukf", note="the symmetric scaling, no per-channel gate")
def mfukf(model, x0, P0, z, sides, p) -> Trace:
    """§5 steps 1–4: χ² test on V = z − ẑ⁻; on failure σ_i = min(σ_max, max(1, (V_i² − R_ii)/A_ii)),
    P⁻' = D_x P⁻ D_x, A' = D_z A D_z, Pxy' = D_x Pxy D_z (rows of H observing one state each; else
    the sigma points are redrawn from (x⁻, P⁻')).
    """
    _check(p)
    if p.form != "symmetric" or p.per_channel_gate > 0:
        raise NotImplementedError("the reference implements the symmetric form without a gate")
    x, P = np.array(x0, float), np.array(P0, float)
    R0 = np.asarray(model.R0, dtype=float)
    xs, Ps, fls = [], [], []
    for k in range(1, z.shape[0]):
        x, P, _ = _predict(model, x, P, k, p)
        o = plain.present(z[k])
        fl = np.zeros(z.shape[1], dtype=np.int8)
        if o.size:
            z_hat, A, Pxy = _measure(model, x, P, k, p, o)
            R = R0[np.ix_(o, o)]
            V = z[k, o] - z_hat
            Pyy = A + R
            if V @ np.linalg.solve(Pyy, V) > p.xi * chi2.ppf(1.0 - p.alpha, o.size):  # 2–3
                fl[o] = 5
                a = np.diag(A)
                sig = np.where(a > 0, (V**2 - np.diag(R)) / np.where(a > 0, a, 1.0), 1.0)
                sig = np.clip(sig, 1.0, p.sigma_max)  # 4  σ_i
                Hk = plain.H(model, x, k)[o]
                obs = np.abs(Hk) > 1e-12 * np.abs(Hk).max(axis=1, keepdims=True)
                s = np.array([max([1.0, *sig[obs[:, j]]]) for j in range(x.size)])  # s_j
                Dx = np.diag(np.sqrt(s))
                if p.recompute_sigma or np.any(obs.sum(axis=1) > 1):
                    P = Dx @ P @ Dx
                    _, A, Pxy = _measure(model, x, P, k, p, o)
                    Pyy = A + R
                else:
                    Dz = np.diag(np.sqrt(sig))
                    P, Pyy, Pxy = Dx @ P @ Dx, Dz @ A @ Dz + R, Dx @ Pxy @ Dz
            K = Pxy @ np.linalg.inv(Pyy)
            x = x + K @ V
            P = P - K @ Pyy @ K.T
        xs.append(x)
        Ps.append(P)
        fls.append(fl)
    return Trace(np.array(xs), np.array(Ps), flags=np.array(fls))
