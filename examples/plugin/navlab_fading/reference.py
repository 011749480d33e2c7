"""The fading-memory KF written plainly: one run, explicit inverse, missing channels deleted.

navlab's contract suite (``navlab check-filter fading-kf``) runs the batched filter beside this
transcription and requires the same numbers.
"""

import numpy as np

from navlab.filters.reference import Trace, reference


@reference("fading-kf")
def fading_kf(model, x0, P0, z, sides, p) -> Trace:
    """x⁻ = f(x), P⁻ = α² F P Fᵀ + Q; then the KF update on the channels present."""
    x, P, xs, Ps = np.asarray(x0, float), np.asarray(P0, float), [], []
    for k in range(1, z.shape[0]):
        F = np.asarray(model.F(k))
        x = model.f(x[None], k)[0]
        P = p.alpha**2 * F @ P @ F.T + model.Q(k)
        o = np.flatnonzero(np.isfinite(z[k]))  # the channels present
        H = np.asarray(model.H(x[None], k)).reshape(-1, model.m, x.size)[0][o]
        nu = z[k, o] - model.h(x[None], k)[0, o]
        R = np.asarray(model.R0)[np.ix_(o, o)]
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        x = x + K @ nu
        P = (np.eye(x.size) - K @ H) @ P @ (np.eye(x.size) - K @ H).T + K @ R @ K.T
        xs.append(x)
        Ps.append(P)
    return Trace(np.array(xs), np.array(Ps))
