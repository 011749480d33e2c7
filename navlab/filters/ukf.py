"""Unscented Kalman filters with SVD sigma points: SVD-UKF and the multiple-fading-factor MFUKF.

Both follow Tan, Wang, Zhao (S2: "RBF-neural-network-aided multiple-fading-factor adaptive SVD-UKF
for GPS/INS", Acta Geodaetica et Cartographica Sinica 44(4), 2015, §2.1–2.2) as restated in
../shared/ALGORITHMS.md §1.3 and §5. S2's equations 1–13 are lost from the seed text; the fading
factor σ_i = max(1, (V_i² − R_ii)/A_ii) and the symmetric scaling of eq. 13 are the spec's
RECONSTRUCTION (§5, §10 items 20–22).

One implementation (STYLE: the textbook step, compiled, is the filter). The steps are written
once, for ONE run, one equation a line with the step numbers of §1.3 and §5 at the lines: the
sigma points (§1.3 a–c), the time update's moments (1–3), the measurement prediction's (4–6), the
innovation, gain and posterior (6–8), the χ² test (§5 2–3) and the fading factors with the faded
update (§5 4). :class:`navlab.jit.RunStep` loops each over the Monte Carlo runs (compiled by
numba; the same Python uncompiled without it, and as the tests' oracle). The model's f and h are
batched callables, so they are applied between the steps to the sigma points of every run at
once (one call on (B·(2n+1), n) rows).

The one batched path: for a model with ``linear = True`` (and the default ``resample="redraw"``)
the moments of §1.3 steps 1–6 are evaluated in closed form over the runs, without the 2n+1 sigma
points (:func:`linear_time_update`, :func:`linear_moments`: the moments of the symmetric sigma
points of a linear map, tested against the steps; ``python benchmarks/tricks.py --trick
ukf-linear-closed-form`` prints what it is worth). A linear map's moments depend on the square
root only through L Lᵀ, so there (and for ``sqrt_method="cholesky"``) the square root is the
Cholesky factor where P is positive definite, the SVD factor elsewhere.

References
----------
S. J. Julier, J. K. Uhlmann, "Unscented filtering and nonlinear estimation", Proc. IEEE 92(3), 2004.
R. van der Merwe, "Sigma-point Kalman filters for probabilistic inference in dynamic state-space
models", PhD thesis, OGI, 2004 (scaled UT weights).
C. Hajiyev, H. E. Soken, "Robust adaptive unscented Kalman filter for attitude estimation of pico
satellites", Int. J. Adapt. Control Signal Process. 28, 2014 (multiple fading factors in a UKF).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from navlab.filters.base import (
    EPOCH_ANOMALY,
    Filter,
    KFLimit,
    Model,
    SideInfo,
    StepOut,
    Teaching,
    flag_fix,
    register,
)
from navlab.jit import Kernel, RunStep
from navlab.linalg import (
    CHOLESKY_LOWER,
    CHOLESKY_SOLVE,
    Array,
    batched,
    chi2_threshold,
    cholesky_lower,
    cholesky_solve,
    mask_missing,
    mT,
    mv,
    sym,
)
from navlab.params import param

SVD, CHOLESKY = 0, 1  # the square root of the sigma points (:func:`square_root`)


class UTWeights(NamedTuple):
    """Scaled unscented-transform weights (ALGORITHMS.md §1.3)."""

    Wm: Array  # (2n+1,)
    Wc: Array  # (2n+1,)
    c: float  # sqrt(n + λ): sigma-point spread

    @property
    def c2(self) -> float:
        """2·Wc_i·c² (i ≥ 1): the weight of L Lᵀ in the UT covariance of a linear map (= 1)."""
        return float(2.0 * self.Wc[1] * self.c * self.c)


@functools.lru_cache(maxsize=64)
def ut_weights(n: int, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0) -> UTWeights:
    """λ = α²(n+κ) − n; Wm_0 = λ/(n+λ); Wc_0 = Wm_0 + 1 − α² + β; Wm_i = Wc_i = 1/(2(n+λ))."""
    lam = alpha**2 * (n + kappa) - n
    if n + lam <= 0:
        from navlab.errors import NavlabError

        raise NavlabError(
            f"unscented transform: n + λ = α²(n+κ) = {n + lam:g} must be > 0; raise alpha_ut or kappa"
        )
    Wm = np.full(2 * n + 1, 0.5 / (n + lam))
    Wc = Wm.copy()
    Wm[0] = lam / (n + lam)
    Wc[0] = lam / (n + lam) + (1.0 - alpha**2 + beta)
    return UTWeights(Wm, Wc, float(np.sqrt(n + lam)))


# ---------------------------------------------------------------------------------------------
# The steps, written for ONE run (navlab.jit.RunStep loops them over the runs, compiled)
# ---------------------------------------------------------------------------------------------


def square_root(P, method):  # pragma: no cover - compiled by numba
    """§1.3 a–b for ONE P: L with L Lᵀ = |P_s|, P_s = (P + Pᵀ)/2, and the negative-definiteness flag.

    SVD (S2): L = U Σ_s^{1/2} from P_s = U Σ_s Tᵀ. For symmetric P_s the singular values are the
    |eigenvalues| and U its eigenvectors (up to sign and order, which leave the symmetric sigma
    points unchanged), so ``eigh`` computes it; a negative eigenvalue becomes its absolute value
    (S2's "suppression of negative definiteness"), flagged where min eig(P_s) < −1e-9·tr P_s.
    CHOLESKY: the Cholesky factor where P_s is positive definite (flag False), else the SVD's.
    A non-finite P (a diverged run) gives NaN, flagged.
    """
    Ps = 0.5 * (P + P.T)  # a  P_s = (P + Pᵀ)/2
    L = np.zeros(P.shape)
    if method == CHOLESKY and cholesky_lower(Ps, L):
        return L, False
    if not np.all(np.isfinite(Ps)):
        return np.full(P.shape, np.nan), True
    w, U = np.linalg.eigh(Ps)  # a  P_s = U Σ_s Tᵀ,  Σ_s = |eig(P_s)|
    return U * np.sqrt(np.abs(w)), w.min() < -1e-9 * abs(np.trace(Ps))  # b  L = U Σ_s^{1/2}


SQUARE_ROOT = Kernel(square_root, uses=(CHOLESKY_LOWER,))


def sigma_points(x, P, c, method):  # pragma: no cover - compiled by numba
    """§1.3 c for ONE run: χ (2n+1, n) of mean x and covariance P (c = √(n+λ)), and the flag of a."""
    L, neg = square_root(P, method)  # a–b
    n = x.shape[0]
    chi = np.empty((2 * n + 1, n))
    chi[0] = x  # c  χ_0 = x̄
    chi[1 : n + 1] = x + c * L.T  # c  χ_j = x̄ + √(n+λ) L_j
    chi[n + 1 :] = x - c * L.T  # c  χ_{j+n} = x̄ − √(n+λ) L_j
    return chi, neg


SIGMA = Kernel(sigma_points, uses=(SQUARE_ROOT,))


def time_update(chi_f, Q, Wm, Wc, c, method, redraw):  # pragma: no cover - compiled by numba
    """§1.3 steps 2–3 for ONE run from the propagated sigma points χ* = f(χ): x⁻, P⁻ and the
    sigma points of the measurement prediction (redrawn from (x⁻, P⁻), or χ*) with their flag.
    """
    x = Wm @ chi_f  # 2  x⁻ = Σ Wm_i χ*_i
    d = chi_f - x
    P = (d.T * Wc) @ d + Q  # 2  P⁻ = Σ Wc_i (χ*_i − x⁻)(χ*_i − x⁻)ᵀ + Q
    P = 0.5 * (P + P.T)
    if not redraw:
        return x, P, chi_f.copy(), False  # 3  (option) reuse χ*
    chi, neg = sigma_points(x, P, c, method)  # 3  redraw χ from (x⁻, P⁻)
    return x, P, chi, neg


def measurement_moments(chi, Y, x, Wm, Wc):  # pragma: no cover - compiled by numba
    """§1.3 steps 4–6 for ONE run from the sigma points χ and their images Y = h(χ): ẑ⁻, A, Pxy."""
    z_hat = Wm @ Y  # 4  ẑ⁻ = Σ Wm_i Y_i
    dY = Y - z_hat
    A = (dY.T * Wc) @ dY  # 5  A = Σ Wc_i (Y_i − ẑ⁻)(Y_i − ẑ⁻)ᵀ
    Pxy = ((chi - x).T * Wc) @ dY  # 6  Pxy = Σ Wc_i (χ_i − x⁻)(Y_i − ẑ⁻)ᵀ
    return z_hat, A, Pxy


def lu_solve(S, B):  # pragma: no cover - compiled by numba
    """S⁻¹ B for ONE S (m, m), B (m, q) by Gaussian elimination with partial pivoting, and False
    where S is singular (a zero pivot). Plain loops: numba compiles them in a fraction of the time
    of the same in array expressions.
    """
    m, q = B.shape
    A, X = S.copy(), B.copy()
    for k in range(m):
        p = k
        for i in range(k + 1, m):
            p = i if abs(A[i, k]) > abs(A[p, k]) else p
        if A[p, k] == 0.0:
            return X, False
        for j in range(m):
            A[k, j], A[p, j] = A[p, j], A[k, j]
        for j in range(q):
            X[k, j], X[p, j] = X[p, j], X[k, j]
        for i in range(k + 1, m):
            f = A[i, k] / A[k, k]
            for j in range(k, m):
                A[i, j] -= f * A[k, j]
            for j in range(q):
                X[i, j] -= f * X[k, j]
    for k in range(m - 1, -1, -1):
        for j in range(q):
            for c in range(k + 1, m):
                X[k, j] -= A[k, c] * X[c, j]
            X[k, j] /= A[k, k]
    return X, True


def solve_rows(S, Y):  # pragma: no cover - compiled by numba
    """X with rows X_i = S⁻¹ Y_i (X = Y S⁻ᵀ) for ONE S (m, m), Y (q, m), and whether S needed a fix.

    Cholesky where S is exactly symmetric and positive definite, LU otherwise (the literal form's
    non-symmetric S); where S is singular, S + 1e-12·tr(S)/m·I (§0.2 rule 3; flag 9).
    """
    m, symmetric = S.shape[0], True
    for i in range(m):
        for j in range(i):
            symmetric = symmetric and S[i, j] == S[j, i]
    L = np.zeros((m, m))
    if symmetric and cholesky_lower(S, L):
        X = Y.copy()
        for i in range(Y.shape[0]):
            cholesky_solve(L, X[i])  # S = L Lᵀ
        return X, False
    X, regular = lu_solve(S, Y.T)
    if not regular:
        X, _ = lu_solve(S + max(1e-12 * np.trace(S) / m, 1e-300) * np.eye(m), Y.T)
    return X.T.copy(), not regular


SOLVE_ROWS = Kernel(solve_rows, uses=(CHOLESKY_LOWER, CHOLESKY_SOLVE, Kernel(lu_solve)))


def gain(P, A, Pxy, R, symmetric):  # pragma: no cover - compiled by numba
    """§1.3 steps 6–8 of the covariance for ONE run: K, P⁺, Pyy and whether Pyy needed a fix.

    ``symmetric`` False: Pyy is left as it is (the literal form of §5, A' = diag(σ) A).
    """
    n, m = Pxy.shape
    Pyy = A + R  # 6  Pyy = A + R
    for i in range(m if symmetric else 0):
        for j in range(i):
            Pyy[i, j] = Pyy[j, i] = 0.5 * (Pyy[i, j] + Pyy[j, i])
    K, fixed = solve_rows(Pyy.T, Pxy)  # 7  K = Pxy Pyy⁻¹
    KPyy = np.zeros((n, m))  # (loops: products of small matrices, no BLAS call and no temporary)
    for i in range(n):
        for c in range(m):
            for d in range(m):
                KPyy[i, d] += K[i, c] * Pyy[c, d]
    P1 = np.empty((n, n))
    for i in range(n):
        for j in range(i, n):
            t = 0.0
            for c in range(m):
                t += KPyy[i, c] * K[j, c] + KPyy[j, c] * K[i, c]
            P1[i, j] = P1[j, i] = 0.5 * (P[i, j] + P[j, i] - t)  # 8  P⁺ = P⁻ − K Pyy Kᵀ, symmetrised
    return K, P1, Pyy, fixed


GAIN = Kernel(gain, uses=(SOLVE_ROWS,))


def chi2_test(V, A, R, ok, thresholds, xi):  # pragma: no cover - compiled by numba
    """§5 steps 2–3 for ONE run: γ = Vᵀ Pyy⁻¹ V against ξ·χ²_{1−α}(channels present).

    ``thresholds[d]``: χ²_{1−α}(d) (d = 0 reads as 1). Returns γ, ξε and whether γ > ξε.
    """
    Pyy = A + R
    X, _ = solve_rows((0.5 * (Pyy + Pyy.T)).T, V.reshape((1, V.shape[0])))
    gamma = V @ X[0]  # 2  γ = Vᵀ Pyy⁻¹ V
    dof = np.sum(ok)
    thr = xi * thresholds[dof]  # ξ ε,  ε = χ²_{1−α}(m)
    return gamma, thr, gamma > thr and dof > 0  # 3  γ > ξ ε: the filter is inconsistent


def fading_update(
    x, P, V, A, Pxy, R, ok, reject, M, sigma_max, gate, literal, recompute
):  # pragma: no cover - compiled by numba
    """§5 step 4 for ONE run: the fading factors σ and the faded update (§1.3 7–8 with P⁻', A', Pxy').

    M (m, n): the states each channel observes (row i of H). σ_i = min(σ_max, max(1, (V_i² −
    R_ii)/A_ii)) on a rejected epoch (1 where the channel is missing or A_ii ≤ 0; with ``gate`` > 0
    only where |V_i|/√Pyy_ii > gate), s_j = the largest σ_i of the channels observing state j (1
    if none). Symmetric form: P⁻' = D_x P⁻ D_x, A' = D_z A D_z, Pxy' = D_x Pxy D_z with
    D = diag(√·); ``literal``: P⁻' = diag(s) P⁻, A' = diag(σ) A, Pxy' = diag(s) Pxy (S2's eq. 13
    style). With σ = 1 it is the SVD-UKF update.

    Where A', Pxy' must come from sigma points of (x⁻, P⁻') — a row of H observes several states, or
    ``recompute`` — and some σ_i > 1, the run is returned with x⁻, P⁻' and ``redo`` True: the caller
    redraws them (h is a batched callable) and does the unscaled update. Returns x⁺, P⁺, Pyy', fixed,
    σ, redo.
    """
    m, n = M.shape
    sig = np.ones(m)
    for i in range(m):
        if reject and ok[i] and A[i, i] > 0.0:  # 4  σ_i = min(σ_max, max(1, (V_i² − R_ii)/A_ii))
            q = (V[i] ** 2 - R[i, i]) / A[i, i]
            sig[i] = sigma_max if q > sigma_max else (1.0 if q < 1.0 else q)
        if gate > 0.0 and not abs(V[i]) > gate * np.sqrt(max(A[i, i] + R[i, i], 1e-300)):
            sig[i] = 1.0  # option per_channel_gate: only |V_i|/√Pyy_ii > gate fades
    s, several = np.ones(n), False
    for i in range(m):  # 4  s_j = σ_i(j): the largest σ_i of the channels observing state j
        several = several or M[i].sum() > 1  # (a row of H observing several states)
        for j in range(n):
            s[j] = max(s[j], sig[i]) if M[i, j] else s[j]
    dx, dz = np.sqrt(s), np.sqrt(sig)  # 4  D_x = diag(√s), D_z = diag(√σ)
    faded = (sig != 1.0).any() or (s != 1.0).any()
    if (recompute or several) and (sig > 1.0).any():  # A', Pxy' from sigma points of P⁻' (caller)
        return x.copy(), dx.reshape((n, 1)) * P * dx, A + R, False, sig, True
    if not faded:  # 3  σ = 1: the ordinary SVD-UKF update
        P1, A1, Pxy1, literal = P, A, Pxy, False
    elif literal:  # S2's eq. 13 style
        P1, A1, Pxy1 = s.reshape((n, 1)) * P, sig.reshape((m, 1)) * A, s.reshape((n, 1)) * Pxy
    else:
        P1 = dx.reshape((n, 1)) * P * dx  # 4  P⁻' = D_x P⁻ D_x
        A1 = dz.reshape((m, 1)) * A * dz  # 4  A' = D_z A D_z
        Pxy1 = dx.reshape((n, 1)) * Pxy * dz  # 4  Pxy' = D_x Pxy D_z
    K, P2, Pyy, fixed = gain(P1, A1, Pxy1, R, not literal)  # 4  Pyy' = A' + R, K = Pxy' Pyy'⁻¹, P⁺
    x1 = x.copy()
    for i in range(n):
        for c in range(m):
            x1[i] += K[i, c] * V[c]  # 4  x⁺ = x⁻ + K V
    return x1, P2, Pyy, fixed, sig, False


def _sigma_shape(x: tuple, *_: tuple) -> tuple[int, int]:
    return (2 * x[0] + 1, x[0])


SQUARE_ROOTS = RunStep(square_root, n_runs=1, outs=((0, float), (None, bool)), uses=(CHOLESKY_LOWER,))
SIGMA_POINTS = RunStep(
    sigma_points, n_runs=2, outs=((_sigma_shape, float), (None, bool)), uses=(SQUARE_ROOT,)
)
TIME_UPDATE = RunStep(
    time_update,
    n_runs=2,
    outs=((lambda chi_f, Q: Q[:1], float), (1, float), (0, float), (None, bool)),
    uses=(SIGMA,),
)
MOMENTS = RunStep(
    measurement_moments,
    n_runs=3,
    outs=(
        (lambda chi, Y, x: Y[1:], float),
        (lambda chi, Y, x: (Y[1], Y[1]), float),
        (lambda chi, Y, x: (x[0], Y[1]), float),
    ),
)
GAIN_STEP = RunStep(
    gain, n_runs=4, outs=((2, float), (0, float), (1, float), (None, bool)), uses=(SOLVE_ROWS,)
)
CHI2_TEST = RunStep(
    chi2_test, n_runs=4, outs=((None, float), (None, float), (None, bool)), uses=(SOLVE_ROWS,)
)
FADING_UPDATE = RunStep(
    fading_update,
    n_runs=9,
    outs=((0, float), (1, float), (3, float), (None, bool), (2, float), (None, bool)),
    uses=(GAIN,),
)


# ---------------------------------------------------------------------------------------------
# Between the steps: f and h of the sigma points; a linear model's moments in closed form
# ---------------------------------------------------------------------------------------------


def propagate(fn: Callable[[Array, int], Array], chi: Array, k: int) -> Array:
    """The model's f or h of every run's sigma points in one call: (B, 2n+1, n) -> (B, 2n+1, ·)."""
    B, N, n = chi.shape
    return np.asarray(fn(chi.reshape(B * N, n), k), dtype=float).reshape(B, N, -1)


def linear_sqrt(P: Array) -> tuple[Array, Array]:
    """§1.3 a–b for a linear model ((n, n) or (B, n, n)): any L with L Lᵀ = |P_s| gives its moments,
    so the Cholesky factor of every P at once (P_s = P: every P the filters carry is exactly
    symmetric), or (where some P is not positive definite) each one's :func:`square_root`.
    """
    try:
        return np.linalg.cholesky(P), np.zeros(P.shape[:-2], dtype=bool)
    except np.linalg.LinAlgError:
        n = P.shape[-1]
        L, neg = SQUARE_ROOTS((P.reshape(-1, n, n),), (CHOLESKY,))
        return L.reshape(P.shape), neg.reshape(P.shape[:-2])


def linear_time_update(model: Model, x: Array, P: Array, k: int, w: UTWeights) -> tuple[Array, ...]:
    """§1.3 steps 1–2 for a linear f, in closed form (the one batched path): with χ_j = x ± c L_j,
    χ*_j − x⁻ = ±c F L_j and x⁻ = F x, so P⁻ = Σ Wc_i (χ*_i − x⁻)(·)ᵀ + Q = 2 Wc_1 c² (F L)(F L)ᵀ + Q.
    Returns x⁻, P⁻ and the flag of a.
    """
    F = model.F(k)
    L, neg = linear_sqrt(P)  # 1  χ from (x⁺, P⁺)
    G = F @ L
    return mv(F, x), sym(w.c2 * (G @ mT(G)) + model.Q(k)), neg  # 2  x⁻ = F x, P⁻


def linear_moments(model: Model, x: Array, P: Array, k: int, w: UTWeights) -> tuple[Array, ...]:
    """§1.3 steps 3–6 for a linear h, in closed form (the one batched path): with χ = x⁻ ± c L_j,
    Y_i − ẑ⁻ = ±c H L_j and ẑ⁻ = H x⁻, so A = 2 Wc_1 c² (H L)(H L)ᵀ and Pxy = 2 Wc_1 c² L (H L)ᵀ.
    Returns ẑ⁻, A, Pxy and the flag of a.
    """
    H = model.H(x, k)
    L, neg = linear_sqrt(P)  # 3  χ = x⁻ ± c L_j
    HL = H @ L
    return mv(H, x), w.c2 * (HL @ mT(HL)), w.c2 * (L @ mT(HL)), neg  # 4–6  ẑ⁻, A, Pxy


def channel_state_map(model: Model, x: Array, k: int) -> Array:
    """Which states each channel inflates: M (B, m, n) bool, row i of H = ∂h/∂x (§5: "the state
    that row i of H observes"; j(i) = i for S2's ordering [δp, δv, …] with H = [I₆ 0]).
    """
    H = np.asarray(model.H(x, k), dtype=float)
    scale = np.max(np.abs(H), axis=-1, keepdims=True)
    return batched(np.abs(H) > 1e-12 * np.maximum(scale, 1e-300), x.shape[0])


# ---------------------------------------------------------------------------------------------
# Filters
# ---------------------------------------------------------------------------------------------


class UKFState(NamedTuple):
    """Per-run state of the UKF family: mean (B, n), covariance (B, n, n), the sigma points of the
    measurement prediction (B, 2n+1, n: redrawn from (x⁻, P⁻), or the propagated χ*; None in the
    closed form) and the negative-definiteness flag of the square roots (B,).
    """

    x: Array
    P: Array
    chi: Array | None = None
    neg: Array | None = None


class Moments(NamedTuple):
    """§1.3 steps 3–6 of every run: ẑ⁻ (B, m), A (B, m, m), Pxy (B, n, m) and the flag of a."""

    z_hat: Array
    A: Array
    Pxy: Array
    neg: Array


@dataclass(frozen=True)
class UKFParams:
    """SVD-UKF options (ALGORITHMS.md §1.3, §10 item 23)."""

    alpha_ut: float = param(1.0, lo=1e-4, hi=1.0, help="sigma-point spread α (S2: 1e-4 … 1)")
    beta_ut: float = param(2.0, lo=0.0, hi=10.0, help="prior-knowledge parameter β (2: Gaussian)")
    kappa: float = param(0.0, lo=-100.0, hi=100.0, help="secondary scaling κ (S2: 0 or 3 − n)")
    resample: str = param(
        "redraw",
        choices=("redraw", "reuse"),
        help="measurement sigma points: redraw from (x⁻, P⁻) (spec default, as FilterPy 2.0.0 does) "
        "or reuse the propagated f(χ) (skips the second set of σ-points; ignores Q's effect on them)",
    )
    sqrt_method: str = param(
        "svd",
        choices=("svd", "cholesky"),
        help="matrix square root of the sigma points: SVD (S2) or Cholesky (a faster step; the "
        "same results for linear models; SVD fallback where P is not positive definite)",
    )


class _UKFBase(Filter):
    """Shared init, time update and measurement moments of the UKF family."""

    family = "nonlinear"
    paper = "Tan, Wang, Zhao 2015 (S2), Acta Geod. Cartogr. Sin. 44(4)"

    def _weights(self, n: int) -> UTWeights:
        p = self.params
        return ut_weights(int(n), float(p.alpha_ut), float(p.beta_ut), float(p.kappa))

    def _method(self, model: Model) -> int:
        """Cholesky where P is positive definite for a linear model (any factor gives its moments)."""
        linear = getattr(model, "linear", False)
        return CHOLESKY if self.params.sqrt_method == "cholesky" or linear else SVD

    def _closed_form(self, model: Model) -> bool:
        """A linear model's moments in closed form (the one batched path; redrawn sigma points)."""
        return bool(getattr(model, "linear", False)) and self.params.resample == "redraw"

    def init(self, model: Model, x0: Array, P0: Array) -> Any:
        x0 = np.array(x0, dtype=float)
        self._weights(x0.shape[1])  # validates n + λ > 0 before the first step
        return self._init_state(model, x0, sym(np.array(P0, dtype=float)))

    def _init_state(self, model: Model, x0: Array, P0: Array) -> Any:
        return UKFState(x0, P0)

    def predict(self, model: Model, state: Any, k: int) -> Any:
        w = self._weights(state.x.shape[1])
        if self._closed_form(model):
            x, P, neg = linear_time_update(model, state.x, state.P, k, w)  # 1–2
            return state._replace(x=x, P=P, chi=None, neg=neg)
        method, redraw, B = self._method(model), self.params.resample == "redraw", state.x.shape[0]
        chi, neg = SIGMA_POINTS((state.x, batched(state.P, B)), (w.c, method))  # 1  χ from (x⁺, P⁺)
        chi_f = propagate(model.f, chi, k)  # 1  χ* = f(χ)
        Q = batched(np.asarray(model.Q(k), dtype=float), B)
        x, P, chi, neg2 = TIME_UPDATE((chi_f, Q), (w.Wm, w.Wc, w.c, method, redraw))  # 2–3
        return state._replace(x=x, P=P, chi=chi, neg=neg | neg2)

    def _moments(self, model: Model, state: Any, k: int) -> Moments:
        """§1.3 steps 3–6 of every run: ẑ⁻, A, Pxy from the state's sigma points (drawn from (x⁻, P⁻)
        where it has none), or in closed form for a linear model.
        """
        w, B = self._weights(state.x.shape[1]), state.x.shape[0]
        neg = state.neg if state.neg is not None else np.zeros(B, dtype=bool)
        if self._closed_form(model):
            z_hat, A, Pxy, neg2 = linear_moments(model, state.x, state.P, k, w)  # 3–6
            return Moments(z_hat, A, Pxy, neg | neg2)
        chi = state.chi
        if chi is None:  # 3  redraw χ from (x⁻, P⁻)
            chi, neg2 = SIGMA_POINTS((state.x, batched(state.P, B)), (w.c, self._method(model)))
            neg = neg | neg2
        Y = propagate(model.h, chi, k)  # 4  Y_i = h(χ_i)
        return Moments(*MOMENTS((chi, Y, state.x), (w.Wm, w.Wc)), neg)  # 4–6  ẑ⁻, A, Pxy


@register
class SVDUKF(_UKFBase):
    """Unscented KF with SVD sigma points, additive noise (ALGORITHMS.md §1.3, S2 §2.1)."""

    key = "svd-ukf"
    label = "SVD-UKF"
    spec_section = "§1.3"
    summary = (
        "Derivative-free unscented KF whose sigma points come from an SVD of P, so they exist even "
        "when round-off makes P indefinite."
    )
    Params = UKFParams
    kf_limit = KFLimit(
        {}, linear_only=True, why="the unscented transform of a linear map is exact: the KF update"
    )
    teaching = Teaching(
        idea=(
            "The unscented KF propagates a small set of sigma points through the nonlinear models "
            "instead of linearising them. Tan et al. build the sigma points from an SVD of P rather "
            "than a Cholesky factor, so they exist even if P loses positive definiteness through "
            "round-off. On a linear model it equals the KF."
        ),
        equations=(
            r"P = U\Sigma_s T^\top, \quad L = U\Sigma_s^{1/2}, \quad "
            r"\chi_0 = \bar x,\ \chi_{j} = \bar x \pm \sqrt{n + \lambda}\,L_j",
            r"x^- = \sum_i W^m_i f(\chi_i), \quad "
            r"P^- = \sum_i W^c_i (\chi^*_i - x^-)(\chi^*_i - x^-)^\top + Q",
            r"Y_i = h(\chi_i),\ \hat z^- = \sum_i W^m_i Y_i,\ "
            r"A = \sum_i W^c_i (Y_i - \hat z^-)(Y_i - \hat z^-)^\top,\ P_{yy} = A + R",
            r"K = P_{xy} P_{yy}^{-1}, \quad x^+ = x^- + K(z - \hat z^-), \quad "
            r"P^+ = P^- - K P_{yy} K^\top",
        ),
        caveat="The tiny example is linear, so the SVD-UKF's steps equal the KF's (to round-off).",
    )

    def update(self, model: Model, state: UKFState, k: int, z: Array, side: SideInfo):
        mo = self._moments(model, state, k)  # 3–6  ẑ⁻, A, Pxy
        mk = mask_missing(z, z - mo.z_hat, model.R0, U=mo.Pxy, M=mo.A)  # 7  V = z − ẑ⁻ (missing: dropped)
        cov = (state.P, mk.M, mk.U, np.asarray(mk.R, dtype=float))
        if all(a.ndim == 2 for a in cov):  # P⁻, A, Pxy, R shared by the runs: K and P⁺ once
            K, P, Pyy, fixed = (a[0] for a in GAIN_STEP(tuple(a[None] for a in cov), (True,)))  # 6–8
        else:
            K, P, Pyy, fixed = GAIN_STEP(tuple(batched(a, z.shape[0]) for a in cov), (True,))  # 6–8
        x = state.x + mv(K, mk.nu)  # 8  x⁺ = x⁻ + K V
        flags = flag_fix(np.zeros(z.shape, dtype=np.int8), fixed | mo.neg)
        return UKFState(x, P), StepOut(x=x, P=P, innov=mk.nu, S=Pyy, R_used=mk.R, flags=flags)


@dataclass(frozen=True)
class MFUKFParams(UKFParams):
    """MFUKF options (ALGORITHMS.md §5, §10 items 20–22)."""

    alpha: float = param(0.05, lo=1e-9, hi=0.5, help="χ² test false-alarm probability (1 − confidence)")
    xi: float = param(1.0, lo=1e-3, hi=1e12, help="scale ξ of the test threshold ξ·χ²_{1−α}(m)")
    sigma_max: float = param(1e6, lo=1.0, hi=1e12, help="cap on each fading factor (navlab guard)")
    form: str = param(
        "symmetric",
        choices=("symmetric", "literal"),
        help="eq. 13 reading: symmetric √σ scaling (default) or S2-style σ·P (non-symmetric)",
    )
    per_channel_gate: float = param(
        0.0,
        lo=0.0,
        hi=100.0,
        help="0: paper rule (every channel with V_i² > A_ii + R_ii fades); c > 0: only |V_i|/√Pyy_ii > c",
    )
    recompute_sigma: bool = param(
        False,
        help="redraw sigma points from the faded P⁻ to get A', Pxy' (exact for any h; automatic "
        "when a measurement row observes several states)",
    )


class Measured(NamedTuple):
    """§5 steps 1–3 of every run: ẑ⁻, V, A, Pxy, R (missing channels dropped), the channels
    present, γ, ξε, the test's verdict and the flag of the sigma points' square roots.
    """

    z_hat: Array
    V: Array
    A: Array
    Pxy: Array
    R: Array
    ok: Array
    gamma: Array
    threshold: Array
    reject: Array
    neg: Array


class _FadingBase(_UKFBase):
    """The χ² test and the fading update shared by MFUKF and NNMFUKF."""

    def _test(self, m: int) -> tuple[Array, float]:
        """The test's parameters: χ²_{1−α}(d) for d = 0 … m (0 reads as 1) and ξ."""
        return chi2_threshold(self.params.alpha, np.arange(m + 1), m), float(self.params.xi)

    def _measure(self, model: Model, state: Any, k: int, z: Array) -> Measured:
        """§5 steps 1–3: the SVD-UKF's measurement prediction (§1.3 3–7) and the χ² test."""
        mo = self._moments(model, state, k)  # 1  ẑ⁻, A, Pxy
        mk = mask_missing(z, z - mo.z_hat, model.R0, U=mo.Pxy, M=mo.A)  # V = z − ẑ⁻ (missing: dropped)
        A, Pxy, R = (batched(np.asarray(a, dtype=float), z.shape[0]) for a in (mk.M, mk.U, mk.R))
        gamma, thr, reject = CHI2_TEST((mk.nu, A, R, mk.ok), self._test(z.shape[1]))  # 2–3
        return Measured(mo.z_hat, mk.nu, A, Pxy, R, mk.ok, gamma, thr, reject, mo.neg)

    def _fade(
        self, model: Model, state: Any, k: int, ms: Measured, V: Array, R: Array, reject: Array
    ) -> tuple[Array, Array, Array, Array, Array]:
        """§5 steps 3–4 of every run with the residual V and noise R (NNMFUKF: replaced). Returns
        x⁺, P⁺, Pyy', fixed (B,) and σ (B, m).
        """
        p, P = self.params, batched(state.P, V.shape[0])
        if not reject.any():  # 3  every run passes: σ = 1, the ordinary SVD-UKF update
            K, P, Pyy, fixed = GAIN_STEP((P, ms.A, ms.Pxy, R), (True,))
            return state.x + mv(K, V), P, Pyy, fixed, np.ones_like(V)
        M = channel_state_map(model, state.x, k)
        opts = (float(p.sigma_max), float(p.per_channel_gate), p.form == "literal", bool(p.recompute_sigma))
        run = (state.x, P, V, ms.A, ms.Pxy, R, ms.ok, reject, M)
        with np.errstate(over="ignore"):  # a diverged run's V_i² may overflow: σ_i = σ_max
            x, P, Pyy, fixed, sig, redo = FADING_UPDATE(run, opts)  # 3–4  σ, the (faded) update
        if redo.any():  # A', Pxy' from sigma points of (x⁻, P⁻') (exact for any h), the unscaled update
            i = np.flatnonzero(redo)
            mo = self._moments(model, UKFState(x[i], P[i]), k)
            z = np.where(ms.ok[i], 0.0, np.nan)  # the channels present (V is the one above)
            mk = mask_missing(z, V[i], U=batched(mo.Pxy, i.size), M=batched(mo.A, i.size))
            run = (x[i], P[i], V[i], mk.M, mk.U, R[i], ms.ok[i], np.zeros(i.size, dtype=bool), M[i])
            x[i], P[i], Pyy[i], fix, _, _ = FADING_UPDATE(run, opts)  # σ = 1: the update with A', Pxy'
            fixed[i] = fix | mo.neg
        return x, P, Pyy, fixed, sig


@register
class MFUKF(_FadingBase):
    """Adaptive SVD-UKF with multiple fading factors (ALGORITHMS.md §5, S2 §2.2; RECONSTRUCTION).

    A χ² test on the predicted residual V = z − ẑ⁻ decides whether the filter is inconsistent; if
    so every observed channel i gets σ_i = max(1, (V_i² − R_ii)/A_ii) and the predicted covariance
    of the state(s) it observes is inflated by σ_i. Reports γ, the threshold and σ in ``stats``
    (``gamma``, ``gamma_threshold``, ``fading``) and flag 5 on every channel of a rejected epoch.
    """

    key = "mfukf"
    label = "MFUKF"
    family = "adaptive"
    spec_section = "§5"
    reconstruction = True
    summary = (
        "SVD-UKF that, when a χ² test on the residual fails, inflates the predicted covariance "
        "channel by channel (one fading factor per observation)."
    )
    Params = MFUKFParams
    kf_limit = KFLimit(
        {"xi": 1e12},
        linear_only=True,
        why="a test threshold ξ·χ² → ∞ never fades: the SVD-UKF, which is the KF on a linear model",
    )
    teaching = Teaching(
        idea=(
            "The multiple-fading-factor SVD-UKF tests the NIS against a χ² threshold; when the test "
            "fails, each observed channel gets its own fading factor σ_i ≥ 1 that inflates the "
            "predicted covariance so the innovation becomes consistent. It absorbs a state anomaly "
            "well, but it also follows a measurement gross error, which is the failure Tan et al. "
            "fix with a neural network."
        ),
        equations=(
            r"V = z - \hat z^-, \qquad \gamma = V^\top P_{yy}^{-1} V",
            r"\gamma \le \xi\varepsilon = \xi\,\chi^2_{1-\alpha}(m)\ \Rightarrow\ "
            r"\text{ordinary SVD-UKF update}",
            r"\sigma_i = \min\!\left(\sigma_{\max}, \max\!\left(1, "
            r"\dfrac{V_i^2 - R_{ii}}{A_{ii}}\right)\right)\qquad\text{(fading factors)}",
            r"P^{-\prime} = D_x P^- D_x,\ A' = D_z A D_z,\ P'_{yy} = A' + R,\ "
            r"P'_{xy} = D_x P_{xy} D_z,\ D = \operatorname{diag}(\sqrt{\sigma})",
        ),
    )

    def update(self, model: Model, state: UKFState, k: int, z: Array, side: SideInfo):
        ms = self._measure(model, state, k, z)  # 1–3  ẑ⁻, V, A, Pxy, the χ² test
        x, P, Pyy, fixed, sig = self._fade(model, state, k, ms, ms.V, ms.R, ms.reject)  # 3–4
        flags = np.zeros(z.shape, dtype=np.int8)
        flags[ms.reject[:, None] & ms.ok] = EPOCH_ANOMALY  # flag 5 on every channel of a rejected epoch
        flag_fix(flags, fixed | ms.neg)
        stats = {"gamma": ms.gamma, "gamma_threshold": ms.threshold, "fading": sig}
        stats["rejected"] = ms.reject.astype(float)
        out = StepOut(x=x, P=P, innov=ms.V, S=Pyy, R_used=ms.R, flags=flags, stats=stats)
        return UKFState(x, P), out
