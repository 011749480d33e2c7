"""Batched linear-algebra kernels shared by every filter.

Shapes: a leading batch axis B (Monte Carlo runs) where a quantity differs between runs, none
where it is shared: ``x`` is (B, n); ``P`` is (n, n) while it is the same in every run (the plain
KF with a common P0) and (B, n, n) once it depends on the data. Everything here broadcasts, so a
filter written with these helpers handles both without branches.
"""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

Array = NDArray[np.float64]


def mT(A: Array) -> Array:
    """Transpose of the last two axes (the method, not np.swapaxes: a hot path, 10× less overhead)."""
    return A.swapaxes(-1, -2)


def mv(A: Array, x: Array) -> Array:
    """Matrix-vector product ``A x`` for A (n, k) or (B, n, k) and x (B, k) -> (B, n)."""
    if A.ndim == 2:
        return x @ A.T
    return (A @ x[..., None])[..., 0]


def sym(P: Array) -> Array:
    """Symmetrise ``(P + Pᵀ)/2`` (ALGORITHMS.md §0.2 rule 1)."""
    return 0.5 * (P + mT(P))


@functools.cache
def cofactor_index(m: int) -> tuple[Array, Array]:
    """Gather indices and signs giving the cofactor matrix C of an m×m matrix (m = 2, 3).

    m = 3 (cyclic rule): C_ij = A[i+1,j+1]A[i+2,j+2] − A[i+1,j+2]A[i+2,j+1], indices mod 3;
    the four factors are gathered in ONE fancy-index operation from the flattened matrix.
    """
    if m == 3:
        i, j = np.divmod(np.arange(9), 3)
        f = lambda a, b: 3 * ((i + a) % 3) + (j + b) % 3  # noqa: E731
        return np.concatenate([f(1, 1), f(2, 2), f(1, 2), f(2, 1)]), np.ones(9)
    return np.array([3, 2, 1, 0]), np.array([1.0, -1.0, -1.0, 1.0])


_ADJ2_SIGN = np.array([[1.0, -1.0], [-1.0, 1.0]])


def bcast(a: Array, shape: tuple[int, ...]) -> Array:
    """``np.broadcast_to`` that returns ``a`` itself when it has the shape already (a hot path:
    broadcast_to costs ≈ 10 µs of Python even then).
    """
    return a if a.shape == shape else np.broadcast_to(a, shape)


def inv_small(S: Array) -> tuple[Array, Array]:
    """Inverse of a stack of small SPD matrices (B, m, m), m ≤ 3, by adjugate/det.

    Returns (S⁻¹, ill) where ``ill`` (B,) marks det ≤ 1e-12·Π diag (the caller then uses LU).
    """
    B, m = S.shape[0], S.shape[-1]
    if m == 2:  # adj(S) = [[d, −b], [−c, a]] by reversing both axes; elementwise, no gather
        a, b, c, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 0], S[:, 1, 1]
        det = a * d - b * c
        ill = ~(det > 1e-12 * (a * d))
        inv = 1.0 / np.where(ill, 1.0, det)
        return S[:, ::-1, ::-1] * _ADJ2_SIGN * inv[:, None, None], ill
    Sf = S.reshape(B, m * m)
    if m == 1:
        cof = np.ones((B, 1))
    else:
        idx, sgn = cofactor_index(m)
        G = Sf[:, idx]
        cof = G[:, 0:9] * G[:, 9:18] - G[:, 18:27] * G[:, 27:36] if m == 3 else G * sgn
    det = np.einsum("bi,bi->b", Sf[:, :m], cof[:, :m])
    ill = ~(det > 1e-12 * np.prod(diag(S), axis=-1))
    inv = 1.0 / np.where(ill, 1.0, det)
    return cof.reshape(B, m, m) * inv[:, None, None], ill


def solve_sym(S: Array, Y: Array) -> tuple[Array, Array]:
    """Solve ``S X = Y`` for symmetric positive-definite S (batched).

    Returns ``(X, fixed)`` where ``fixed`` (B,) or () is True where S was singular and
    ``1e-12·trace(S)/m·I`` had to be added (§0.2 rule 3; flag 9). A LU solve is used: for SPD S
    it is the same solution as Cholesky and numpy batches it natively.
    """
    try:
        return np.linalg.solve(S, Y), np.zeros(S.shape[:-2], dtype=bool)
    except np.linalg.LinAlgError:
        m = S.shape[-1]
        jitter = 1e-12 * np.trace(S, axis1=-2, axis2=-1)[..., None, None] / m
        jitter = np.maximum(jitter, 1e-300) * np.eye(m)
        try:
            cond = np.linalg.cond(S)
            fixed = ~np.isfinite(cond) | (cond > 1e14)
        except np.linalg.LinAlgError:
            fixed = np.ones(S.shape[:-2], dtype=bool)
        return np.linalg.solve(S + jitter, Y), fixed


_SEL_CACHE: dict[tuple, Array | None] = {}


def selection(H: Array) -> Array | None:
    """Column indices if H is a shared 0/1 selection matrix (one 1 per row), else None."""
    if H.ndim != 2:
        return None
    key = (H.shape, H.tobytes())
    if key not in _SEL_CACHE:
        is_sel = np.all((H == 0.0) | (H == 1.0)) and np.all(H.sum(axis=1) == 1.0)
        if len(_SEL_CACHE) > 64:
            _SEL_CACHE.clear()
        _SEL_CACHE[key] = np.argmax(H, axis=1) if is_sel else None
    return _SEL_CACHE[key]


def PHt(P: Array, H: Array) -> tuple[Array, Array]:
    """``U = P Hᵀ`` and ``H P Hᵀ = H U``; by indexing when H selects states (exact: the products
    are with 1 and the sums with 0; a stacked matmul costs ≈ 10× more).
    """
    sel = selection(H)
    if sel is not None:
        U = P[..., sel]
        return U, U[..., sel, :]
    if H.ndim == 2 and P.ndim == 3:  # shared H: each product as one GEMM (see predict_cov)
        B, n, _ = P.shape
        m = H.shape[0]
        U = (P.reshape(B * n, n) @ H.T).reshape(B, n, m)
        HUt = np.ascontiguousarray(mT(U)).reshape(B * m, n) @ H.T  # rows (H U)ᵀ
        return U, mT(HUt.reshape(B, m, m))
    U = P @ mT(H)
    return U, H @ U


def kf_gain(U: Array, S: Array) -> tuple[Array, Array]:
    """Kalman gain ``K = U S⁻¹`` (U = P Hᵀ); returns (K, fixed) with the result and the flag of
    an LU solve (:func:`solve_sym`), faster.

    For a batched S with m ≤ 3 the closed-form inverse (adjugate/det, no LAPACK call). Where any
    S is ill-conditioned (det ≤ 1e-12·Π diag, every singular S included) the whole batch takes
    the LU path of :func:`solve_sym`, so ``fixed`` (flag 9) marks exactly the runs that needed
    jitter.
    """
    if S.ndim == 3 and S.shape[-1] <= 3:
        Sinv, ill = inv_small(S)
        if not ill.any():
            return U @ Sinv, ill  # all False
    Kt, fixed = solve_sym(S, mT(U))
    return mT(Kt), fixed


def joseph_from_gain(P: Array, K: Array, U: Array, S: Array) -> Array:
    """The Joseph form ``(I−KH) P (I−KH)ᵀ + K R Kᵀ`` from U = P Hᵀ and S = H P Hᵀ + R, symmetrised.

    Its exact expansion P − U Kᵀ − K Uᵀ + K S Kᵀ = P − U Kᵀ + K (K S − U)ᵀ, valid for any gain K:
    three n×m products instead of two n×n×n ones — the filter has U and S already.
    """
    return sym(P - U @ mT(K) + K @ mT(K @ S - U))


def quad(v: Array, S: Array) -> Array:
    """Quadratic form ``vᵀ S⁻¹ v`` for v (B, m), S (m, m) or (B, m, m) -> (B,)."""
    if S.ndim == 2:
        return np.einsum("bi,bi->b", v, np.linalg.solve(S, v.T).T)
    if S.shape[-1] == 2:  # closed form: (s11 v0² − 2 s01 v0 v1 + s00 v1²) / det S
        a, b, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
        v0, v1 = v[:, 0], v[:, 1]
        return (d * v0 * v0 - 2.0 * b * v0 * v1 + a * v1 * v1) / (a * d - b * b)
    return np.einsum("bi,bi->b", v, np.linalg.solve(S, v[..., None])[..., 0])


def diag(A: Array) -> Array:
    """Diagonal of the last two axes."""
    return A.diagonal(axis1=-2, axis2=-1)


def diag_embed(d: Array) -> Array:
    """(B, m) -> (B, m, m) diagonal matrices (written through a strided view, no eye product)."""
    B, m = d.shape
    out = np.zeros((B, m, m))
    out.reshape(B, m * m)[:, :: m + 1] = d
    return out


def mask_missing(z: Array, nu: Array, H: Array, R: Array) -> tuple[Array, Array, Array, Array]:
    """Drop unavailable channels (NaN in ``z``) exactly.

    A missing channel i gets a zero innovation, a zero row in H and a unit, uncorrelated R_ii, so
    its gain column is exactly zero and S stays invertible. With every channel present the inputs
    come back unchanged (and unbatched).

    Returns
    -------
    ok : (B, m) bool, channel available.
    nu, H, R : masked copies (batched where masking was needed).
    """
    ok = np.isfinite(z)
    if ok.all():
        return ok, nu, H, R
    B, m = z.shape
    nu = np.where(ok, nu, 0.0)
    H = np.broadcast_to(H, (B, *H.shape[-2:])) * ok[..., None]
    okk = ok[:, :, None] & ok[:, None, :]
    R = np.where(okk, np.broadcast_to(R, (B, m, m)), 0.0) + np.eye(m) * (~ok)[:, None, :]
    return ok, nu, H, R


def eigh_clamp(R: Array, lo: float, hi: float) -> tuple[Array, Array]:
    """Clamp the eigenvalues of symmetric R (batched) into [lo, hi]; returns (R', clamped (B,))."""
    R = sym(R)
    w, V = np.linalg.eigh(R)
    clamped = np.any((w < lo) | (w > hi), axis=-1)
    w = np.clip(w, lo, hi)
    return (V * w[..., None, :]) @ mT(V), clamped


def predict_cov(F: Array, P: Array, Q: Array) -> Array:
    """``F P Fᵀ + Q``, symmetrised; for a shared F (n, n) and batched P (B, n, n) as two GEMMs.

    numpy's stacked matmul of small matrices loops over the batch; reshaping (B, n, n) to
    (B·n, n) turns each product into one BLAS call. Uses Pᵀ = P: with X = P Fᵀ, F P Fᵀ = Xᵀ Fᵀ.
    """
    if F.ndim != 2 or P.ndim != 3:
        return sym(F @ P @ mT(F) + Q)
    B, n, _ = P.shape
    X = (P.reshape(B * n, n) @ F.T).reshape(B, n, n)  # P Fᵀ
    Z = (np.ascontiguousarray(mT(X)).reshape(B * n, n) @ F.T).reshape(B, n, n)  # (F P) Fᵀ
    return sym(Z + Q)


@functools.lru_cache(maxsize=64)
def _chi2_table(alpha: float, m: int) -> Array:
    return chi2.ppf(1.0 - alpha, np.maximum(np.arange(m + 1), 1))


def chi2_threshold(alpha: float, dof: Array | int, m: int) -> Array:
    """χ²_{1−α}(dof) for dof ∈ 0 … m (dof 0 reads as 1), from a cached table (scipy's ppf is slow)."""
    return _chi2_table(float(alpha), int(m))[dof]
