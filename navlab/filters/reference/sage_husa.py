"""Plain references of the Sage–Husa family (§4.1–4.9): SHAKF, IRAKF, RRAE, RAKF, RSSHAKF.

One run, explicit inverses, the eigenvalue clamp by a full eigen-decomposition every epoch and
the residual window as a list; default options only (each function says which it implements).
"""

from __future__ import annotations

import numpy as np

from navlab.filters.reference import Trace, plain, reference
from navlab.filters.sage_husa.kernels import forgetting_weight, rhat_bounds
from navlab.linalg import eigh_clamp


def _sage_husa(R_prev, nu, HPH, o, d, lo, hi, diagonal=False):
    """§4.1 steps 3–4 on the observed channels o (others keep R̂_{k−1}), then the clamp."""
    R = R_prev.copy()
    io = np.ix_(o, o)
    if diagonal:  # §4.9: the simplified per-channel form
        r = (1 - d) * np.diag(R_prev)[o] + d * (nu**2 - np.diag(HPH))
        R[o, o] = np.clip(r, lo, hi)
        return R
    R[io] = (1 - d) * R_prev[io] + d * (np.outer(nu, nu) - HPH)
    return eigh_clamp(R, lo, hi)[0]


@reference("sage-husa", note="R only (full=False)")
def sage_husa(model, x0, P0, z, sides, p) -> Trace:
    """§4.1: R̂_k = (1 − d_k) R̂_{k−1} + d_k (ννᵀ − H P⁻ Hᵀ), clamped; the KF update with R̂_k."""
    if p.full:
        raise NotImplementedError("the reference implements the R-only Sage–Husa filter")
    x, P = np.array(x0, float), np.array(P0, float)
    R0 = np.asarray(model.R0, dtype=float)
    R = R0.copy()
    lo, hi = rhat_bounds(R0)
    xs, Ps, Rs = [], [], []
    for k in range(1, z.shape[0]):
        x, P = plain.kf_predict(model, x, P, k)
        o = plain.present(z[k])
        if o.size:
            Hk = plain.H(model, x, k)[o]
            nu = z[k, o] - plain.h(model, x, k)[o]
            if p.adapt:
                R = _sage_husa(R, nu, Hk @ P @ Hk.T, o, forgetting_weight(k, p.b), lo, hi)
            x, P, _ = plain.kf_step(x, P, nu, Hk, R[np.ix_(o, o)])
        xs.append(x)
        Ps.append(P)
        Rs.append(R.copy())
    return Trace(np.array(xs), np.array(Ps), np.array(Rs))


def _rae(window, M, R0, HPH_ref):
    """S1 eqs. 3/4: (1/M) Σ η ηᵀ over the last M residuals + H P_ref Hᵀ (R0 until the window is full).

    A channel missing at some epochs averages over the epochs it was present (Ŝ = D Σ ηηᵀ D,
    D = diag(1/√c_i), ALGORITHMS.md §4.2 as navlab reads it); one never present gets R0_ii.
    """
    if len(window) < M:
        return R0.copy()
    E = np.array([e for e, _ in window[-M:]])  # (M, m), 0 where missing
    ok = np.array([o for _, o in window[-M:]])
    c = ok.sum(axis=0)
    D = np.diag(np.where(c > 0, 1.0 / np.sqrt(np.maximum(c, 1)), 0.0))
    S_hat = D @ (E.T @ E) @ D + np.diag(np.where(c == 0, np.diag(R0), 0.0))
    return S_hat + HPH_ref


@reference("irakf", note="the default options (Huber middle segment on ν, ungated parallel KF)")
def irakf(model, x0, P0, z, sides, p) -> Trace:
    """§4.6 steps 1–7."""
    if p.middle_segment != "huber" or p.middle_zone != "innovation" or p.skf_gated:
        raise NotImplementedError("the reference implements the default IRAKF options")
    x, P = np.array(x0, float), np.array(P0, float)
    xs_, Ps_ = x.copy(), P.copy()  # the parallel standard KF
    R0 = np.asarray(model.R0, dtype=float)
    lo, hi = rhat_bounds(R0)
    m = z.shape[1]
    window: list = []
    out_x, out_P, out_R, out_w, out_f = [], [], [], [], []
    for k in range(1, z.shape[0]):
        P_post = P
        x, P = plain.kf_predict(model, x, P, k)  # 2
        o = plain.present(z[k])
        zo = z[k, o]
        flag_s = np.zeros(m, dtype=bool)
        if p.dual_detection:  # 1  parallel SKF: detect, then its own ungated update
            xs_, Ps_ = plain.kf_predict(model, xs_, Ps_, k)
            if o.size:
                Hs = plain.H(model, xs_, k)[o]
                nu_s = zo - plain.h(model, xs_, k)[o]
                Ss = Hs @ Ps_ @ Hs.T + R0[np.ix_(o, o)]
                flag_s[o] = np.abs(nu_s) > p.C * np.sqrt(np.diag(Ss))
                xs_, Ps_, _ = plain.kf_step(xs_, Ps_, nu_s, Hs, R0[np.ix_(o, o)])
        Hfull = plain.H(model, x, k)
        P_ref = P if {"always": True, "never": False}.get(p.improved_rae, flag_s.any()) else P_post
        R_hat = _rae(window, p.window, R0, Hfull @ P_ref @ Hfull.T)  # 3
        if len(window) >= p.window:
            R_hat = eigh_clamp(R_hat, lo, hi)[0]
        w = np.ones(m)
        fl = np.zeros(m, dtype=np.int8)
        if o.size:
            Hk = Hfull[o]
            nu = zo - plain.h(model, x, k)[o]
            Ro = R_hat[np.ix_(o, o)]
            S = Hk @ P @ Hk.T + Ro  # 4
            K = P @ Hk.T @ np.linalg.inv(S)
            a = np.abs(nu) / np.sqrt(np.diag(S))  # |ν̃_i|
            own = a > p.k1
            aux = flag_s[o] & ~own
            down = (a > p.k0) & ~own & ~aux
            K[:, own | aux] = 0.0  # 5  zero the gain columns
            wo = np.where(own | aux, 0.0, np.where(down, p.k0 / np.where(down, a, 1.0), 1.0))
            x = x + K @ (np.where(down, wo, 1.0) * nu)  # 6
            P = plain.joseph(P, K, Hk, Ro)
            w[o] = wo
            fl[o] = np.where(own, 2, np.where(aux, 3, np.where(down, 1, 0)))
        eta = np.zeros(m)
        eta[o] = zo - plain.h(model, x, k)[o]  # 7  raw posterior residual into the window
        window.append((eta, np.isfinite(z[k])))
        out_x.append(x)
        out_P.append(P)
        out_R.append(R_hat)
        out_w.append(w)
        out_f.append(fl)
    return Trace(*(np.array(a) for a in (out_x, out_P, out_R, out_w, out_f)))


@reference("rrae", note="form='equivalent_variance'")
def rrae(model, x0, P0, z, sides, p) -> Trace:
    """§4.7 steps 1–6 (IGG-III equivalent variance, ν_i ← 0 beyond k1, short-form P)."""
    if p.form != "equivalent_variance":
        raise NotImplementedError("the reference implements the equivalent-variance form")
    x, P = np.array(x0, float), np.array(P0, float)
    R0 = np.asarray(model.R0, dtype=float)
    lo, hi = rhat_bounds(R0)
    m = z.shape[1]
    window: list = []
    out = [[], [], [], [], []]
    for k in range(1, z.shape[0]):
        P_post = P
        x, P = plain.kf_predict(model, x, P, k)
        Hfull = plain.H(model, x, k)
        R_hat = _rae(window, p.window, R0, Hfull @ P_post @ Hfull.T)  # 1  eq. 3
        if len(window) >= p.window:
            R_hat = eigh_clamp(R_hat, lo, hi)[0]
        o = plain.present(z[k])
        w = np.ones(m)
        fl = np.zeros(m, dtype=np.int8)
        if o.size:
            Hk = Hfull[o]
            nu = z[k, o] - plain.h(model, x, k)[o]
            Ro = R_hat[np.ix_(o, o)]
            a = np.abs(nu) / np.sqrt(np.diag(Hk @ P @ Hk.T + Ro))  # 2
            mid = (a > p.k0) & (a <= p.k1)
            rej = a > p.k1
            wo = np.ones(o.size)
            wo[mid] = (p.k0 / a[mid]) * ((p.k1 - a[mid]) / (p.k1 - p.k0)) ** 2  # 3  IGG-III
            wo[rej] = 0.0
            R_bar = Ro.copy()
            R_bar[mid, mid] = Ro[mid, mid] / wo[mid]  # 4  equivalent variance
            K = P @ Hk.T @ np.linalg.inv(Hk @ P @ Hk.T + R_bar)  # 5
            x = x + K @ np.where(rej, 0.0, nu)
            P = (np.eye(x.size) - K @ Hk) @ P
            w[o] = wo
            fl[o] = np.where(rej, 2, np.where(mid, 1, 0))
        eta = np.zeros(m)
        eta[o] = z[k, o] - plain.h(model, x, k)[o]  # 6
        window.append((eta, np.isfinite(z[k])))
        for lst, v in zip(out, (x, P, R_hat, w, fl), strict=True):
            lst.append(v)
    return Trace(*(np.array(a) for a in out))


@reference("rakf")
def rakf(model, x0, P0, z, sides, p) -> Trace:
    """§4.8 steps 1–5."""
    x, P = np.array(x0, float), np.array(P0, float)
    R0 = np.asarray(model.R0, dtype=float)
    R = R0.copy()
    lo, hi = rhat_bounds(R0)
    m = z.shape[1]
    out = [[], [], [], [], []]
    for k in range(1, z.shape[0]):
        x, P = plain.kf_predict(model, x, P, k)  # 1
        o = plain.present(z[k])
        w = np.ones(m)
        fl = np.zeros(m, dtype=np.int8)
        if o.size:
            Hk = plain.H(model, x, k)[o]
            nu = z[k, o] - plain.h(model, x, k)[o]
            if p.adapt:  # 2
                R = _sage_husa(R, nu, Hk @ P @ Hk.T, o, forgetting_weight(k, p.b), lo, hi)
            Ro = R[np.ix_(o, o)]
            HPH = Hk @ P @ Hk.T
            if nu @ nu > p.gamma_s * np.trace(HPH + Ro):  # 3  abnormal: inflate P⁻
                P = max(1.0, (nu @ nu - np.trace(Ro)) / np.trace(HPH)) * P
                fl[o] = 5
            S = Hk @ P @ Hk.T + Ro  # 4
            L = np.linalg.cholesky(S)
            e = np.linalg.solve(L, nu)
            clip = np.abs(e) > p.c
            nu_c = L @ np.clip(e, -p.c, p.c)
            K = P @ Hk.T @ np.linalg.inv(S)  # 5
            x = x + K @ nu_c
            P = plain.joseph(P, K, Hk, Ro)
            w[o] = np.where(clip, p.c / np.where(clip, np.abs(e), 1.0), 1.0)
            fl[o] = np.where(clip, 1, fl[o])
        for lst, v in zip(out, (x, P, R.copy(), w, fl), strict=True):
            lst.append(v)
    return Trace(*(np.array(a) for a in out))


@reference("rsshakf", note="exclude_outliers=False")
def rsshakf(model, x0, P0, z, sides, p) -> Trace:
    """§4.9 steps 1–5 (diagonal R̂, the Sage–Husa update on every channel)."""
    if p.exclude_outliers:
        raise NotImplementedError("the reference implements the default reading")
    x, P = np.array(x0, float), np.array(P0, float)
    R0 = np.asarray(model.R0, dtype=float)
    R = np.diag(np.diag(R0))
    lo, hi = rhat_bounds(R0)
    m = z.shape[1]
    out = [[], [], [], [], []]
    for k in range(1, z.shape[0]):
        x, P = plain.kf_predict(model, x, P, k)
        o = plain.present(z[k])
        w = np.ones(m)
        fl = np.zeros(m, dtype=np.int8)
        if o.size:
            Hk = plain.H(model, x, k)[o]
            nu = z[k, o] - plain.h(model, x, k)[o]
            HPH = Hk @ P @ Hk.T
            Ro = R[np.ix_(o, o)]
            a = np.abs(nu) / np.sqrt(np.diag(HPH + Ro))  # 1
            out_ch = a > p.c_r  # 2
            R_used = Ro.copy()
            R_used[out_ch, out_ch] = Ro[out_ch, out_ch] * a[out_ch] / p.c_r  # 3
            x, P, _ = plain.kf_step(x, P, nu, Hk, R_used)  # 4
            if p.adapt:  # 5
                R = _sage_husa(R, nu, HPH, o, forgetting_weight(k, p.b), lo, hi, diagonal=True)
            w[o] = np.where(out_ch, p.c_r / np.where(out_ch, a, 1.0), 1.0)
            fl[o] = out_ch
        for lst, v in zip(out, (x, P, R.copy(), w, fl), strict=True):
            lst.append(v)
    return Trace(*(np.array(a) for a in out))
