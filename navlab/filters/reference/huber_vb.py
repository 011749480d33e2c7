"""Plain reference of the Huber KF (§2), one run.

The VB filters (vb-akf, hakf, student-t-kf) have none: their one-run step
(:func:`navlab.filters.huber_vb.vb_iterations`) is the implementation, compared compiled against
uncompiled (tests/unit/test_jit_kernels.py) and with the numbers pinned before it was written
(tests/unit/test_linear_pinned.py).
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
