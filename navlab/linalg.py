"""Batched small-matrix linear algebra: the layer below filters, scenarios, noise and the INS.

Shapes: a leading batch axis B (Monte Carlo runs) where a quantity differs between runs, none
where it is shared: ``x`` is (B, n); ``P`` is (n, n) while it is the same in every run (the plain
KF with a common P0) and (B, n, n) once it depends on the data. Everything here broadcasts, so a
filter written with these helpers handles both without branches.

Why the kernels look the way they do: with B runs of tiny matrices, numpy's per-call overhead,
not arithmetic, is the cost (a stacked LAPACK call on 2×2 systems costs far more than its arithmetic), so
a few kernels take a shorter road than the textbook formula. Each states the formula it equals
(to round-off) and is tested against it (tests/contract/test_kernel_properties.py, hypothesis
over B, n, m and missing-channel patterns). A shortcut stays only where it saves ≥ 10 % of some
filter's time; ``python benchmarks/tricks.py --trick NAME`` re-measures it (its output, never this
docstring, holds the figures):

* :func:`selection`, :func:`PHt` — P Hᵀ and H P Hᵀ by indexing when H selects states
  (``PHt-indexing``), H's structure cached by its content (``selection-cache``);
* :func:`kf_gain` — K = U S⁻¹ from the closed-form inverse (:func:`inv_small`) for m ≤ 3
  (``kf_gain-closed-form``);
* :func:`joseph_from_gain` — the Joseph form by its exact expansion from U and S;
* :func:`bcast` — a broadcast view built directly (``bcast-view``);
* :func:`select` — no ``np.where`` while the mask is everywhere true (``select-none-masks``);
* :func:`chi2_threshold` — χ² quantiles from a cached table;
* :func:`quad` — the quadratic form vᵀ S⁻¹ v, one dispatcher for every shape
  (``quad-shortcuts``): closed form for d ≤ 2, LDLᵀ with the batch axes last for d = 3, LU for
  d ≥ 4; the method never depends on the batch, so a run's value is the same in any chunk.

Compiled (navlab.jit, each kernel written for one run, its numpy path the reference, compared in
tests/unit/test_jit_kernels.py): :func:`solve_sym` and :func:`quad` (d ≥ 4) by Cholesky, LU where
S is not exactly symmetric and positive definite; :func:`joseph_from_gain` in one pass.

Measured below 10 % and removed (the figures are in the commit history, not here): F P Fᵀ and
P Hᵀ as two GEMMs on the stacked rows for a shared F or H; F P Fᵀ + Q compiled for one run; P Fᵀ
as one GEMM on the stacked rows of P in :func:`predict_cov` and M L likewise for the UKF's linear
transform (a row of a GEMM over the run axis also rounds differently by the size of the batch; a
stacked product multiplies each run's matrices by themselves).
"""

from __future__ import annotations

import contextlib
import functools
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.special import gammaincinv

from navlab.jit import Kernel, carray

Array = NDArray[np.float64]

# OpenBLAS runs a GEMM on one thread when M·N·K ≤ 65536·4 and on all CPUs above. On a small shared
# machine a threaded GEMM can wait many times its own cost for a busy CPU, so the large products of
# the RBF network's training (navlab.filters.rbf.mm) are split into pieces below that size.
SERIAL_GEMM = 65536 * 4


# ------------------------------------------------------------------------------ shapes
def mT(A: Array) -> Array:
    """Transpose of the last two axes (the array method: less call overhead than np.swapaxes)."""
    return A.swapaxes(-1, -2)


def mv(A: Array, x: Array) -> Array:
    """Matrix-vector product ``A x`` for A (n, k) or (B, n, k) and x (B, k) -> (B, n)."""
    if A.ndim == 2:
        return x @ A.T
    return (A @ x[..., None])[..., 0]


def sym(P: Array) -> Array:
    """Symmetrise ``(P + Pᵀ)/2`` (ALGORITHMS.md §0.2 rule 1); the result is exactly symmetric."""
    return 0.5 * (P + mT(P))


def diag(A: Array) -> Array:
    """Diagonal of the last two axes."""
    return A.diagonal(axis1=-2, axis2=-1)


def diag_embed(d: Array) -> Array:
    """(B, m) -> (B, m, m) diagonal matrices (written through a strided view, no eye product)."""
    B, m = d.shape
    out = np.zeros((B, m, m))
    out.reshape(B, m * m)[:, :: m + 1] = d
    return out


def bcast(a: Array, shape: tuple[int, ...]) -> Array:
    """``np.broadcast_to(a, shape)``: a read-only view (``a`` itself when it has the shape).

    A C-contiguous ``a`` that only gains leading axes gets its zero-stride view built directly
    (``np.broadcast_to`` is called every epoch; ``benchmarks/tricks.py --trick bcast-view``).
    """
    a = np.asarray(a)
    if a.shape == shape:
        return a
    lead = len(shape) - a.ndim
    if lead > 0 and shape[lead:] == a.shape and a.flags.c_contiguous and a.size:
        v = np.ndarray(shape, a.dtype, a, 0, (0,) * lead + a.strides)
        v.flags.writeable = False
        return v
    return np.broadcast_to(a, shape)


def zero_columns(K: Array, reject: Array) -> Array:
    """The gain K (n, m) or (B, n, m) with column i zeroed where ``reject[b, i]``: (B, n, m)."""
    return bcast(K, (reject.shape[0], *K.shape[-2:])) * ~reject[:, None, :]


def select(mask: Array | None, new: Array, old: Array | float) -> Array:
    """``np.where(mask, new, old)``, with ``mask`` None meaning "everywhere": the usual case —
    every channel present, every run still iterating — then costs no ``np.where`` at all.
    """
    return new if mask is None else np.where(mask, new, old)


def batched(A: Array, B: int) -> Array:
    """Matrix ``A`` (r, c) or (B, r, c) with a leading run axis: (B, r, c), a read-only view when
    ``A`` is shared (``.copy()`` it for a per-run array of one's own).
    """
    return A if A.ndim > 2 else bcast(A, (B, *A.shape))


# ------------------------------------------------------------------------------ products of the KF
@functools.lru_cache(maxsize=128)
def _selection(shape: tuple[int, ...], data: bytes) -> Array | None:
    H = np.frombuffer(data).reshape(shape)
    is_sel = np.all((H == 0.0) | (H == 1.0)) and np.all(H.sum(axis=1) == 1.0)
    if not is_sel:
        return None
    cols = np.argmax(H, axis=1)
    cols.flags.writeable = False
    return cols


def selection(H: Array) -> Array | None:
    """Column indices if H is a shared 0/1 selection matrix (one 1 per row), else None.

    Cached by H's content (``functools.lru_cache`` is safe under the app's threads).
    """
    if H.ndim != 2:
        return None
    H = np.ascontiguousarray(H, dtype=float)
    return _selection(H.shape, H.tobytes())


def PHt(P: Array, H: Array) -> tuple[Array, Array]:
    """``U = P Hᵀ`` and ``M = H P Hᵀ = H U`` (P symmetric).

    By indexing when H selects states (exact: the products are with 1 and the sums with 0; a
    stacked matmul costs several times more), the plain products otherwise.
    """
    sel = selection(H)
    if sel is not None:
        U = P[..., sel]
        return U, U[..., sel, :]
    U = P @ mT(H)
    return U, H @ U


def predict_cov(F: Array, P: Array, Q: Array) -> Array:
    """``F P Fᵀ + Q``, symmetrised (§1.1 step 2)."""
    return sym(F @ P @ mT(F) + Q)


# ------------------------------------------------------------------------------ inverses and solves
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


def cofactors(Sf: Array, m: int) -> Array:
    """Cofactor matrix C of each symmetric m×m matrix (m ≤ 3), flattened: (B, m²) -> (B, m²).

    adj(S) = Cᵀ = C for symmetric S, so S⁻¹ = C / det S with det S = Σ_j S_0j C_0j.
    """
    if m == 1:
        return np.ones_like(Sf)
    idx, sgn = cofactor_index(m)
    G = Sf[:, idx]
    return G * sgn if m == 2 else G[:, 0:9] * G[:, 9:18] - G[:, 18:27] * G[:, 27:36]


_ADJ2_SIGN = np.array([[1.0, -1.0], [-1.0, 1.0]])


def inv_small(S: Array) -> tuple[Array, Array]:
    """Inverse of a stack of small SPD matrices (B, m, m), m ≤ 3, by adjugate/det (closed form).

    m = 2: adj(S) = [[d, −b], [−c, a]], S with both axes reversed and the signs flipped, element
    by element (no gather); m = 1, 3: the cofactors of :func:`cofactors`. Returns (S⁻¹, ill)
    where ``ill`` (B,) marks det ≤ 1e-12·Π diag (the caller then uses LU); an ill run's inverse
    is not meaningful.
    """
    B, m = S.shape[0], S.shape[-1]
    if m == 2:
        a, b, c, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 0], S[:, 1, 1]
        det = a * d - b * c
        ill = ~(det > 1e-12 * (a * d))
        inv = 1.0 / np.where(ill, 1.0, det)
        return S[:, ::-1, ::-1] * _ADJ2_SIGN * inv[:, None, None], ill
    Sf = np.ascontiguousarray(S).reshape(B, m * m)
    cof = cofactors(Sf, m)
    det = Sf[:, 0] * cof[:, 0]  # det S = Σ_j S_0j C_0j
    for j in range(1, m):
        det = det + Sf[:, j] * cof[:, j]
    ill = ~(det > 1e-12 * np.prod(diag(S), axis=-1))
    inv = 1.0 / np.where(ill, 1.0, det)
    return cof.reshape(B, m, m) * inv[:, None, None], ill


def inv_spd(S: Array) -> tuple[Array, Array]:
    """``S⁻¹`` of symmetric positive-definite S (B, m, m) and the runs that needed a fix.

    The closed form (:func:`inv_small`) for m ≤ 3, the LU solve ``S X = I`` of :func:`solve_sym`
    otherwise or where any S of the stack is ill-conditioned (``fixed`` marks the runs that
    needed jitter, flag 9).
    """
    if S.shape[-1] <= 3:
        Sinv, ill = inv_small(S)
        if not ill.any():
            return Sinv, ill
    return solve_sym(S, np.eye(S.shape[-1]))


def solve_sym(S: Array, Y: Array) -> tuple[Array, Array]:
    """Solve ``S X = Y`` for symmetric positive-definite S (batched).

    Returns ``(X, fixed)`` where ``fixed`` (B,) or () is True where S was singular and
    ``1e-12·trace(S)/m·I`` had to be added (§0.2 rule 3; flag 9). A LU solve is used: for SPD S
    it is the same solution as Cholesky and numpy batches it natively. Compiled (navlab.jit), for
    S (m, m) or (B, m, m) and Y (m, q) or (B, m, q): a Cholesky solve per run (:func:`_solve_runs`),
    the LU below (the reference) for the runs whose S is not exactly symmetric and positive
    definite.
    """
    kernel = _SOLVE.get() if S.ndim in (2, 3) and Y.ndim in (2, 3) else None
    if kernel is None:
        return _solve_lu(S, Y)
    B, batched_ = _lead(S, Y)
    m, q = S.shape[-1], Y.shape[-1]
    X = np.empty((B, m, q))
    ok = np.empty(B, dtype=bool)
    kernel(_stack3(S), _stack3(Y), X, ok)
    fixed = np.zeros(B, dtype=bool)
    if not ok.all():
        bad = np.flatnonzero(~ok)
        X[bad], fixed[bad] = _solve_lu(bcast(S, (B, m, m))[bad], bcast(Y, (B, m, q))[bad])
    # the shapes of the LU's: X batched if S or Y is, ``fixed`` S's leading shape (a shared S: ())
    return X if batched_ else X[0], fixed if S.ndim == 3 else fixed[0]


def _solve_runs(S, Y, X, ok):  # pragma: no cover - compiled by numba
    """X[r] = S_r⁻¹ Y_r by Cholesky S = L Lᵀ, one run at a time (a leading 1: shared by every run).

    ok[r] = False where S_r is not exactly symmetric or not positive definite (X_r undefined).
    """
    B, m, q = X.shape
    L = np.empty((m, m))
    y = np.empty(m)
    for r in range(B):
        Sr = S[r if S.shape[0] > 1 else 0]
        Yr = Y[r if Y.shape[0] > 1 else 0]
        sym_ = True
        for i in range(m):
            for j in range(i + 1, m):
                if Sr[i, j] != Sr[j, i]:
                    sym_ = False
        ok[r] = sym_ and cholesky_lower(Sr, L)
        if not ok[r]:
            continue
        for c in range(q):
            for i in range(m):
                y[i] = Yr[i, c]
            cholesky_solve(L, y)
            for i in range(m):
                X[r, i, c] = y[i]


def _solve_lu(S: Array, Y: Array) -> tuple[Array, Array]:
    """:func:`solve_sym` by LU (numpy), with jitter where S is singular."""
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


# ------------------------------------------------------------------------------ the KF update
def cholesky_lower(S, L):  # pragma: no cover - compiled by numba
    """Lower Cholesky factor L of one symmetric m×m S (S = L Lᵀ); False if S is not positive definite.

    A helper of the compiled kernels (navlab.jit: ``Kernel(..., uses=(CHOLESKY_LOWER,))``).
    """
    m = S.shape[0]
    for j in range(m):
        d = S[j, j]
        for c in range(j):
            d -= L[j, c] * L[j, c]
        if not d > 0.0:  # not positive definite (or NaN)
            return False
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, m):
            s = S[i, j]
            for c in range(j):
                s -= L[i, c] * L[j, c]
            L[i, j] = s / L[j, j]
        for i in range(j):
            L[i, j] = 0.0
    return True


def cholesky_solve(L, y):  # pragma: no cover - compiled by numba
    """Solve S x = y in place (y ← S⁻¹ y) for S = L Lᵀ: L w = y forward, then Lᵀ y = w backward.

    A helper of the compiled kernels.
    """
    m = L.shape[0]
    for i in range(m):
        s = y[i]
        for c in range(i):
            s -= L[i, c] * y[c]
        y[i] = s / L[i, i]
    for i in range(m - 1, -1, -1):
        s = y[i]
        for c in range(i + 1, m):
            s -= L[c, i] * y[c]
        y[i] = s / L[i, i]


def forward_substitute(L, G):  # pragma: no cover - compiled by numba
    """G ← L⁻¹ G in place for a lower-triangular L (m, m) and G (m, p): L Y = G, row by row.

    A helper of the compiled kernels.
    """
    m, p = G.shape
    for j in range(p):
        for i in range(m):
            s = G[i, j]
            for c in range(i):
                s -= L[i, c] * G[c, j]
            G[i, j] = s / L[i, i]


CHOLESKY_LOWER = Kernel(cholesky_lower)
FORWARD_SUBSTITUTE = Kernel(forward_substitute)
CHOLESKY_SOLVE = Kernel(cholesky_solve)
_SOLVE = Kernel(_solve_runs, uses=(CHOLESKY_LOWER, CHOLESKY_SOLVE))


def _lead(*arrays: Array) -> tuple[int, bool]:
    """(B, batched): the run count of stacked (3-D) arrays among ``arrays`` (1 if none is)."""
    B = max((a.shape[0] for a in arrays if a.ndim == 3), default=1)
    return B, any(a.ndim == 3 for a in arrays)


def _stack3(a: Array) -> Array:
    """``a`` as a C-contiguous float 3-D stack (a leading 1 for a shared matrix)."""
    return carray(a if a.ndim == 3 else a[None])


def kf_gain(U: Array, S: Array) -> tuple[Array, Array]:
    """Kalman gain ``K = U S⁻¹`` (U = P Hᵀ); returns (K, fixed) with the result and the flag of
    :func:`solve_sym` (an LU solve, or compiled a Cholesky solve per run), faster.

    For a batched S with m ≤ 3 the closed-form inverse (adjugate/det, no LAPACK call). Where any
    S is ill-conditioned (det ≤ 1e-12·Π diag, every singular S included) the whole batch takes
    :func:`solve_sym`, so ``fixed`` (flag 9) marks exactly the runs that needed jitter.
    """
    if S.ndim == 3 and S.shape[-1] <= 3:
        Sinv, ill = inv_small(S)
        if not ill.any():
            return U @ Sinv, ill  # all False
    Kt, fixed = solve_sym(S, mT(U))
    return mT(Kt), fixed


def _joseph_runs(P, K, U, S, out):  # pragma: no cover - compiled by numba
    """out[r] = P − U Kᵀ + K (K S − U)ᵀ, symmetrised, one run at a time (see joseph_from_gain).

    Every argument (1 or B, …): a leading 1 is shared by every run. With W = K S − U, row i of
    P − U Kᵀ + K Wᵀ is P_i + Σ_c (K_ic W_c − U_ic K_c) over the columns c of K (rows of Kᵀ, Wᵀ).
    """
    B, n, _ = out.shape
    m = K.shape[2]
    Wt = np.empty((m, n))  # (K S − U)ᵀ
    Kt = np.empty((m, n))
    A = np.empty((n, n))
    for r in range(B):
        Pr = P[r if P.shape[0] > 1 else 0]
        Kr = K[r if K.shape[0] > 1 else 0]
        Ur = U[r if U.shape[0] > 1 else 0]
        Sr = S[r if S.shape[0] > 1 else 0]
        for c in range(m):
            for i in range(n):
                Kt[c, i] = Kr[i, c]
                Wt[c, i] = -Ur[i, c]
            for d in range(m):
                s = Sr[d, c]
                for i in range(n):
                    Wt[c, i] += Kr[i, d] * s
        for i in range(n):  # A = P − U Kᵀ + K Wᵀ
            for j in range(n):
                A[i, j] = Pr[i, j]
            for c in range(m):
                a, b = Kr[i, c], Ur[i, c]
                for j in range(n):
                    A[i, j] += a * Wt[c, j] - b * Kt[c, j]
        for i in range(n):  # symmetrise (§0.2 rule 1)
            out[r, i, i] = A[i, i]
            for j in range(i + 1, n):
                v = 0.5 * (A[i, j] + A[j, i])
                out[r, i, j] = v
                out[r, j, i] = v


_JOSEPH = Kernel(_joseph_runs)


def joseph_from_gain(P: Array, K: Array, U: Array, S: Array) -> Array:
    """The Joseph form ``(I−KH) P (I−KH)ᵀ + K R Kᵀ`` from U = P Hᵀ and S = H P Hᵀ + R, symmetrised.

    Its exact expansion P − U Kᵀ − K Uᵀ + K S Kᵀ = P − U Kᵀ + K (K S − U)ᵀ, valid for any gain K:
    three n×m products instead of two n×n×n ones — the filter has U and S already. Compiled
    (navlab.jit, one pass over each run's P: :func:`_joseph_runs`); the numpy expression below is
    the reference.
    """
    kernel = _JOSEPH.get()
    if kernel is not None:
        B, batched_ = _lead(P, K, U, S)
        out = np.empty((B, *P.shape[-2:]))
        kernel(_stack3(P), _stack3(K), _stack3(U), _stack3(S), out)
        return out if batched_ else out[0]
    return sym(P - U @ mT(K) + K @ mT(K @ S - U))


class Masked(NamedTuple):
    """Measurement-update inputs with the unavailable channels dropped (:func:`mask_missing`)."""

    ok: Array  # (B, m) bool: channel available
    nu: Array  # innovation, 0 on missing channels
    R: Array | None  # R with a unit, uncorrelated R_ii on missing channels
    H: Array | None = None  # H with zero rows on missing channels
    U: Array | None = None  # P Hᵀ (the UKF's Pxy) with zero columns on missing channels
    M: Array | None = None  # H P Hᵀ (the UKF's A) with zero rows and columns on missing channels


def mask_missing(
    z: Array,
    nu: Array,
    R: Array | None = None,
    *,
    H: Array | None = None,
    U: Array | None = None,
    M: Array | None = None,
) -> Masked:
    """Drop the unavailable channels (NaN in ``z``) of a measurement update exactly.

    A missing channel i gets ν_i = 0, a zero row i of H (so a zero column i of U = P Hᵀ and a
    zero row and column i of M = H P Hᵀ) and a unit, uncorrelated R_ii: S = M + R stays
    invertible, block-diagonal in (i, the rest), so the gain column K[:, i] = (U S⁻¹)[:, i] is
    exactly zero and the update equals the update with channel i removed. Give whichever of R, H,
    U, M the filter uses. With every channel present the inputs come back unchanged (unbatched).
    """
    ok = np.isfinite(z)
    if ok.all():
        return Masked(ok, nu, R, H, U, M)
    B, m = z.shape
    okk = ok[:, :, None] & ok[:, None, :]
    nu = np.where(ok, nu, 0.0)
    if R is not None:
        R = np.where(okk, bcast(R, (B, m, m)), 0.0) + np.eye(m) * (~ok)[:, None, :]
    if H is not None:
        H = bcast(H, (B, *H.shape[-2:])) * ok[..., None]
    if U is not None:
        U = bcast(U, (B, *U.shape[-2:])) * ok[:, None, :]
    if M is not None:
        M = np.where(okk, bcast(M, (B, m, m)), 0.0)
    return Masked(ok, nu, R, H, U, M)


def eigh_clamp(R: Array, lo: float, hi: float) -> tuple[Array, Array]:
    """Clamp the eigenvalues of symmetric R (batched) into [lo, hi]; returns (R', clamped (B,))."""
    R = sym(R)
    w, V = np.linalg.eigh(R)
    clamped = np.any((w < lo) | (w > hi), axis=-1)
    w = np.clip(w, lo, hi)
    return (V * w[..., None, :]) @ mT(V), clamped


def chi2_ppf(p: Array | float, dof: Array | float) -> Array:
    """The χ²(dof) quantile of probability p: ``scipy.stats.chi2.ppf(p, dof)``, the same bits, from
    the special function it calls (importing scipy.stats would slow the start of every process).
    """
    return 2.0 * gammaincinv(np.asarray(dof) / 2.0, p)


@functools.lru_cache(maxsize=64)
def _chi2_table(alpha: float, m: int) -> Array:
    return chi2_ppf(1.0 - alpha, np.maximum(np.arange(m + 1), 1))


def chi2_threshold(alpha: float, dof: Array | int, m: int) -> Array:
    """χ²_{1−α}(dof) for dof ∈ 0 … m (dof 0 reads as 1), from a cached table (scipy's ppf is slow)."""
    return _chi2_table(float(alpha), int(m))[dof]


# ------------------------------------------------------------------------------ quadratic forms
def quad(v: Array, S: Array) -> Array:
    """The quadratic form ``vᵀ S⁻¹ v`` (NIS, NEES), one dispatcher for every shape.

    Parameters
    ----------
    v : (..., d).
    S : (d, d) shared by every v, or (..., d, d) broadcastable to v's leading axes (an S constant
        along the axis before the matrix axes — stride 0, e.g. the KF's P shared by every run —
        is factored once).

    Returns
    -------
    (...,) values; NaN where S is singular or not finite (never an exception).

    The method depends on d and on whether S is shared, never on the batch, so a value depends on
    its own v and S only, never on the other runs of the chunk it was computed with: the closed
    form for d ≤ 2; for d = 3 an unpivoted LDLᵀ elimination with the batch axes last (stable for
    positive-definite S; a shared S factored once); for d ≥ 4 an LU solve per matrix (LAPACK), or,
    for a shared S, its inverse once and the form element by element (equal to a solve per run to
    round-off); ``benchmarks/tricks.py --trick quad-shortcuts`` measures them.
    Compiled (navlab.jit), d ≥ 4: a Cholesky factor per distinct matrix (a shared S factored once)
    and |L⁻¹ v|² (:func:`_quad_runs`); the numpy paths above are its reference.
    LU, one matrix at a time, also decides the entries a shortcut could not (a zero pivot or a
    zero determinant of a singular or indefinite S).
    """
    v = np.asarray(v, dtype=float)
    S = np.asarray(S, dtype=float)
    d = v.shape[-1]
    if d > 3:
        kernel = _QUAD.get()
        if kernel is not None:
            return _quad_cholesky(kernel, v, S)
        if S.ndim == 2 or (S.ndim >= 3 and S.strides[-3] == 0):
            q = _quad_shared(v, S)
            if q is not None:
                return q
        Sb = np.broadcast_to(S, (*v.shape, d))
        return _quad_lu(v.reshape(-1, d), Sb.reshape(-1, d, d)).reshape(v.shape[:-1])
    # a singular or indefinite S legitimately gives inf/NaN in the shortcuts: redone by LU below
    with np.errstate(all="ignore"):
        if d <= 2:
            q = np.asarray(_quad_closed(v, S))
        else:
            shared = S.ndim >= 3 and S.shape[-3] > 1 and S.strides[-3] == 0
            Sm = S[..., :1, :, :] if shared else S
            Sm = Sm.reshape((1,) * (v.ndim + 1 - Sm.ndim) + Sm.shape)  # one batch axis per v's
            q = np.asarray(_quad_ldl(np.moveaxis(v, -1, 0), np.moveaxis(Sm, (-2, -1), (0, 1))))
        q = np.broadcast_to(q, v.shape[:-1]).copy() if q.shape != v.shape[:-1] else q
        if np.isfinite(q).all():
            return q
        Sb = np.broadcast_to(S, (*v.shape, d))
        redo = ~np.isfinite(q) & np.isfinite(v).all(axis=-1) & np.isfinite(Sb).all(axis=(-2, -1))
    if redo.any():
        q[redo] = _quad_lu(v[redo], Sb[redo])
    return q


def _quad_runs(v, S, rep, q, ok):  # pragma: no cover - compiled by numba
    """q[i] = vᵢᵀ Sⱼ⁻¹ vᵢ = |L⁻¹ vᵢ|² (Sⱼ = L Lᵀ, j = i // rep: an S shared by ``rep`` consecutive v's
    is factored once); ok[i] = False where Sⱼ is not exactly symmetric or not positive definite
    (q[i] undefined).
    """
    N, d = v.shape
    L = np.empty((d, d))
    y = np.empty(d)
    last = -1
    good = False
    for i in range(N):
        j = i // rep
        if j != last:
            good = True  # exactly symmetric (the factor reads one triangle only) and positive definite
            for a in range(d):
                for c in range(a + 1, d):
                    if S[j, a, c] != S[j, c, a]:
                        good = False
            good = good and cholesky_lower(S[j], L)
            last = j
        ok[i] = good
        if not good:
            continue
        s = 0.0
        for a in range(d):  # forward substitution L y = v, q = Σ y²
            t = v[i, a]
            for c in range(a):
                t -= L[a, c] * y[c]
            y[a] = t / L[a, a]
            s += y[a] * y[a]
        q[i] = s


_QUAD = Kernel(_quad_runs, uses=(CHOLESKY_LOWER,))


def _quad_cholesky(kernel, v: Array, S: Array) -> Array:
    """:func:`quad` by the compiled Cholesky kernel; LU decides where S is not exactly symmetric and
    positive definite.
    """
    lead, d = v.shape[:-1], v.shape[-1]
    N = int(np.prod(lead))
    if N == 0:
        return np.zeros(lead)
    vf = carray(v.reshape(N, d))
    if S.ndim == 2:
        Sf, rep = S[None], N
    else:
        Sb = np.broadcast_to(S, (*lead, d, d))
        if Sb.ndim >= 3 and Sb.strides[-3] == 0:  # constant along the last batch axis (a shared P)
            Sf, rep = Sb[..., 0, :, :].reshape(-1, d, d), lead[-1]
        else:
            Sf, rep = Sb.reshape(-1, d, d), 1
    q = np.empty(N)
    ok = np.empty(N, dtype=bool)
    kernel(vf, carray(Sf), rep, q, ok)
    if not ok.all():
        bad = np.flatnonzero(~ok)
        Sbad = Sf[bad // rep]
        q[bad] = np.nan
        redo = np.isfinite(vf[bad]).all(axis=-1) & np.isfinite(Sbad).all(axis=(-2, -1))
        if redo.any():
            q[bad[redo]] = _quad_lu(vf[bad[redo]], Sbad[redo])
    return q.reshape(lead)


def _quad_shared(v: Array, S: Array) -> Array | None:
    """vᵀ S⁻¹ v for an S shared along the axis before its matrix axes (the KF's P, the same for
    every run): S inverted once per distinct matrix (LAPACK), then q = Σᵢ vᵢ Σₖ vₖ (S⁻¹)ₖᵢ element by
    element in a fixed order, so a value does not depend on the batch. None (the caller falls
    back to LU per matrix) where an S is singular or not finite.
    """
    d = v.shape[-1]
    Su = S if S.ndim == 2 else S[..., :1, :, :]  # the distinct matrices
    if not np.isfinite(Su).all():
        return None
    try:
        inv = np.linalg.inv(Su)
    except np.linalg.LinAlgError:
        return None
    q = np.zeros(v.shape[:-1])
    with np.errstate(over="ignore", invalid="ignore"):  # a run-away's v is inf: its value inf/NaN
        for i in range(d):
            y = v[..., 0] * inv[..., 0, i]
            for k in range(1, d):
                y += v[..., k] * inv[..., k, i]
            q += y * v[..., i]
    return q


def _quad_closed(v: Array, S: Array) -> Array:
    """D = 1: v²/s; d = 2: (s11 v0² − 2 s01 v0 v1 + s00 v1²)/det S (any leading axes)."""
    if v.shape[-1] == 1:
        return v[..., 0] * v[..., 0] / S[..., 0, 0]
    a, b, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 1]
    v0, v1 = v[..., 0], v[..., 1]
    return (d * v0 * v0 - 2.0 * b * v0 * v1 + a * v1 * v1) / (a * d - b * b)


def _quad_lu(v: Array, S: Array) -> Array:
    """vᵀ S⁻¹ v for v (N, d), S (N, d, d) by LU; NaN where S is singular."""
    try:
        return np.einsum("bi,bi->b", v, np.linalg.solve(S, v[..., None])[..., 0])
    except np.linalg.LinAlgError:  # a singular S somewhere: NaN only where it is
        q = np.full(v.shape[0], np.nan)
        for i in range(q.size):
            with contextlib.suppress(np.linalg.LinAlgError):
                q[i] = v[i] @ np.linalg.solve(S[i], v[i])
        return q


def _quad_ldl(v: Array, S: Array) -> Array:
    """vᵀ S⁻¹ v by symmetric elimination S = L D Lᵀ (no pivoting: stable for positive-definite S).

    ``S`` is (d, d, *s) and ``v`` (d, *t) with the batch axes last and ``s`` broadcastable to
    ``t``: a covariance shared by many runs is factored once, and every run's value is computed
    with exactly the arithmetic it would get alone. q = Σᵢ yᵢ²/Dᵢ with L y = v.
    """
    d = S.shape[0]
    A = np.array(S, dtype=float)  # the elimination works in place
    y = np.array(v, dtype=float)
    q = np.zeros(np.broadcast_shapes(S.shape[2:], v.shape[1:]))
    for i in range(d):
        piv = A[i, i]
        q += y[i] ** 2 / piv
        if i + 1 < d:
            f = A[i + 1 :, i] / piv
            A[i + 1 :, i:] -= f[:, None] * A[i, i:][None]
            y[i + 1 :] = y[i + 1 :] - f * y[i]
    return q
