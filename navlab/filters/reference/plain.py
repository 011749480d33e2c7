"""The textbook building blocks of the reference filters (one run, explicit inverses)."""

from __future__ import annotations

import numpy as np

from navlab.linalg import Array


def f(model, x: Array, k: int) -> Array:
    """f(x) for one state vector (n,)."""
    return np.asarray(model.f(x[None], k), dtype=float)[0]


def h(model, x: Array, k: int) -> Array:
    """h(x) for one state vector (n,) -> (m,)."""
    return np.asarray(model.h(x[None], k), dtype=float)[0]


def H(model, x: Array, k: int) -> Array:
    """The measurement Jacobian at x, (m, n)."""
    J = np.asarray(model.H(x[None], k), dtype=float)
    return J[0] if J.ndim == 3 else J


def F(model, x: Array, k: int) -> Array:
    """The transition Jacobian (the model's ``F_at(x⁺)`` if it has one, else ``F(k)``), (n, n)."""
    F_at = getattr(model, "F_at", None)
    A = np.asarray(F_at(x[None], k) if F_at is not None else model.F(k), dtype=float)
    return A[0] if A.ndim == 3 else A


def Q(model, k: int) -> Array:
    Qk = np.asarray(model.Q(k), dtype=float)
    return Qk[0] if Qk.ndim == 3 else Qk


def kf_predict(model, x: Array, P: Array, k: int, jacobian_at_x: bool = False) -> tuple[Array, Array]:
    """x⁻ = f(x⁺), P⁻ = F P⁺ Fᵀ + Q (§1.1 steps 1–2); the EKF (§1.2) takes F at x⁺."""
    A = F(model, x, k) if jacobian_at_x else np.asarray(model.F(k), dtype=float)
    A = A[0] if A.ndim == 3 else A
    return f(model, x, k), A @ P @ A.T + Q(model, k)


def joseph(P: Array, K: Array, Hk: Array, R: Array) -> Array:
    """(I − K H) P (I − K H)ᵀ + K R Kᵀ."""
    IKH = np.eye(P.shape[0]) - K @ Hk
    return IKH @ P @ IKH.T + K @ R @ K.T


def kf_step(x: Array, P: Array, nu: Array, Hk: Array, R: Array) -> tuple[Array, Array, Array]:
    """The KF measurement update (§1.1 steps 3–6): S, K = P Hᵀ S⁻¹, x + K ν, Joseph. Returns x, P, K."""
    S = Hk @ P @ Hk.T + R
    K = P @ Hk.T @ np.linalg.inv(S)
    return x + K @ nu, joseph(P, K, Hk, R), K


def present(z: Array) -> Array:
    """Indices of the available channels of z (m,)."""
    return np.flatnonzero(np.isfinite(z))
