"""Unscented Kalman filters with SVD sigma points: SVD-UKF and the multiple-fading-factor MFUKF.

Both follow Tan, Wang, Zhao (S2: "RBF-neural-network-aided multiple-fading-factor adaptive SVD-UKF
for GPS/INS", Acta Geodaetica et Cartographica Sinica 44(4), 2015, §2.1–2.2) as restated in
../shared/ALGORITHMS.md §1.3 and §5. S2's equations 1–13 are lost from the seed text; the fading
factor σ_i = max(1, (V_i² − R_ii)/A_ii) and the symmetric scaling of eq. 13 are the spec's
RECONSTRUCTION (§5, §10 items 20–22).

Batched: x (B, n), P (B, n, n), sigma points (B, 2n+1, n); ``f(·, k)`` and ``h(·, k)`` are called
once per sigma point on a (B, n) batch, as the Model protocol allows. The step numbers of §1.3
and §5 stand at the lines that implement them.

Speed tricks kept (each re-measured by ``python benchmarks/tricks.py --trick NAME``; the plain
sigma-point transcription, one run, is :mod:`navlab.filters.reference.ukf`, and the contract
tests compare every filter with it):

* for a model with ``linear = True`` the unscented transform is evaluated in closed form (the
  moments of the symmetric sigma points of a linear map, :func:`ukf_time_update`;
  ``ukf-linear-closed-form``), with a Cholesky factor as the square root where P is positive
  definite (:func:`linear_sqrt`: any factor gives the same moments of a linear map; the SVD
  repair where it is not; ``ukf-linear-cholesky``);
* the SVD "square root" of a symmetric P through ``eigh`` (:func:`svd_sqrt`: the same sigma
  points as ``svd``, column order and signs aside; ``ukf-svd-by-eigh``);
* MFUKF/NNMFUKF: the χ² test's solve also gives the unfaded gain, and only the runs whose
  factors are not all 1 are solved again (:meth:`_FadingBase._fade`; ``ukf-fade-subset``).

Measured below 10 % and removed: a "P is PSD by construction" flag in the state that skipped the
Cholesky factor, a cache of the channel-to-state map.

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
from navlab.linalg import (
    Array,
    batched,
    bcast,
    chi2_threshold,
    diag,
    mask_missing,
    mT,
    mv,
    solve_sym,
    sym,
)
from navlab.params import param

# ---------------------------------------------------------------------------------------------
# Unscented-transform kernels (pure functions, batched)
# ---------------------------------------------------------------------------------------------


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


def svd_sqrt(P: Array) -> tuple[Array, Array]:
    """SVD "square root" L = U·diag(√s) of (P + Pᵀ)/2, and a negative-definiteness flag.

    ALGORITHMS.md §1.3 a–b. For symmetric P the singular values are |eigenvalues| and the singular
    vectors are the eigenvectors (up to sign), so the factor is computed with ``eigh`` (the same L
    up to column order and sign, which leave the symmetric sigma-point set unchanged; ~2× faster than
    ``svd`` on stacked 15×15). A negative eigenvalue is thus silently replaced by its absolute value
    (S2's "suppression of negative definiteness"); the flag (shape P.shape[:-2]) is True where
    min eig(P_s) < −1e-9·trace(P_s).
    """
    Ps = sym(P)
    w, U = np.linalg.eigh(Ps)
    tr = np.trace(Ps, axis1=-2, axis2=-1)[..., None]
    neg = np.any(w < -1e-9 * np.abs(tr), axis=-1)
    return U * np.sqrt(np.abs(w))[..., None, :], neg


def chol_sqrt(P: Array) -> tuple[Array, Array]:
    """Cholesky factor of (P + Pᵀ)/2 (option ``sqrt_method="cholesky"``); where any P of the stack
    is not positive definite the whole stack falls back to :func:`svd_sqrt` (and its flag).
    """
    Ps = sym(P)
    try:
        return np.linalg.cholesky(Ps), np.zeros(Ps.shape[:-2], dtype=bool)
    except np.linalg.LinAlgError:
        return svd_sqrt(Ps)


def linear_sqrt(P: Array, symmetric: bool = False) -> tuple[Array, Array]:
    """A square root L (L Lᵀ = |P_s|) for the unscented transform of a LINEAR map, and the flag.

    For linear f, h the sigma-point moments depend on the square root only through L Lᵀ, so any
    factor gives the same x⁻, P⁻, A, Pxy. Where (P + Pᵀ)/2 is positive definite (Cholesky succeeds)
    L Lᵀ = P_s = |P_s| up to round-off: the Cholesky factor (≈ 17× cheaper than ``eigh`` on a stack
    of 15×15) gives the SVD sigma points' moments, and the flag is False (a successful Cholesky
    bounds min eig(P_s) ≥ −O(n·eps·‖P_s‖), far above −1e-9·trace(P_s)). Where any P of the stack
    is not positive definite, the whole stack takes :func:`svd_sqrt` (the SVD repair |P_s| and its
    flag, exactly as before). ``symmetric``: P is known to be exactly symmetric (the output of
    :func:`sym`), so the symmetrisation is skipped (it would return P bit for bit).
    """
    Ps = P if symmetric else sym(P)
    try:
        return np.linalg.cholesky(Ps), np.zeros(Ps.shape[:-2], dtype=bool)
    except np.linalg.LinAlgError:
        return svd_sqrt(Ps)


def sigma_points(x: Array, P: Array, c: float, method: str = "svd") -> tuple[Array, Array]:
    """Symmetric sigma points χ (B, 2n+1, n) of mean x (B, n) and P ((n, n) or (B, n, n)).

    ``method``: "svd" (S2, default) or "cholesky" (faster; identical results for linear f, h,
    different sigma points otherwise).
    """
    L, neg = chol_sqrt(P) if method == "cholesky" else svd_sqrt(P)
    D = c * mT(L)  # rows = c·L_j
    B, n = x.shape
    D = np.broadcast_to(D, (B, n, n))
    chi = np.concatenate([x[:, None, :], x[:, None, :] + D, x[:, None, :] - D], axis=1)
    return chi, np.broadcast_to(neg, (B,))


def ut_mean_cov(Y: Array, w: UTWeights) -> tuple[Array, Array, Array]:
    """Weighted mean (B, p) and covariance (B, p, p) of sigma images Y (B, 2n+1, p), and Y − mean."""
    mean = np.einsum("i,bip->bp", w.Wm, Y)
    d = Y - mean[:, None, :]
    cov = mT(d * w.Wc[None, :, None]) @ d
    return mean, cov, d


def ut_cross(dX: Array, dY: Array, w: UTWeights) -> Array:
    """Cross covariance Σ Wc_i dX_i dY_iᵀ (B, n, p)."""
    return mT(dX * w.Wc[None, :, None]) @ dY


def propagate_f(model: Model, chi: Array, k: int) -> Array:
    """f(χ_i, k) for every sigma point: (B, 2n+1, n) -> (B, 2n+1, n)."""
    if getattr(model, "linear", False):
        F = model.F(k)
        return chi @ mT(F)  # (n,n) or (B,n,n): both broadcast over the sigma axis
    return np.stack([model.f(chi[:, i], k) for i in range(chi.shape[1])], axis=1)


def propagate_h(model: Model, chi: Array, k: int) -> Array:
    """h(χ_i, k) for every sigma point: (B, 2n+1, n) -> (B, 2n+1, m)."""
    if getattr(model, "linear", False):
        H = model.H(chi[:, 0], k)
        return chi @ mT(H)
    return np.stack([model.h(chi[:, i], k) for i in range(chi.shape[1])], axis=1)


class UKFState(NamedTuple):
    """Per-run state of the UKF family: mean (B, n), covariance (B, n, n), propagated sigma points
    (kept only for the ``reuse`` option) and the time update's negative-definiteness flag (B,).
    """

    x: Array
    P: Array
    chi_f: Array | None = None
    neg: Array | None = None


class MeasPred(NamedTuple):
    """Measurement prediction of §1.3 steps 3–6 (R not yet added)."""

    z_hat: Array  # (B, m)
    A: Array  # (B, m, m) sigma-point covariance of h WITHOUT R
    Pxy: Array  # (B, n, m)
    neg: Array  # (B,) SVD repaired a negative-definite P (this step)


def ukf_time_update(
    model: Model,
    x: Array,
    P: Array,
    k: int,
    w: UTWeights,
    keep_sigma: bool = False,
    method: str = "svd",
    symmetric: bool = False,
) -> UKFState:
    """§1.3 steps 1–2: χ from (x⁺, P⁺); χ* = f(χ); x⁻ = Σ Wm χ*; P⁻ = Σ Wc (χ* − x⁻)(·)ᵀ + Q.

    For a linear f (``model.linear``) the unscented transform is evaluated in closed form (the
    speed trick this module keeps; the sigma-point path below is its reference): with
    χ_j = x ± c·L_j, χ*_j − x⁻ = ±c·F L_j and x⁻ = F x (the symmetric images average to the
    centre), so P⁻ = Σ Wc_i (χ*_i − x⁻)(·)ᵀ + Q = 2·Wc_1·c² (F L)(F L)ᵀ + Q, without building the
    2n+1 points. ``keep_sigma`` (option ``resample="reuse"``) keeps the propagated χ*.
    ``symmetric``: P is exactly symmetric already (every P the filters carry is), so the
    symmetrisation of step a is skipped (it would return P bit for bit).
    """
    B = x.shape[0]
    if not keep_sigma and getattr(model, "linear", False):
        F = model.F(k)
        L, neg = linear_sqrt(P, symmetric)  # any square root: L Lᵀ = |P_s| (SVD repair where P_s ≱ 0)
        G = F @ L
        P_p = sym(w.c2 * (G @ mT(G)) + model.Q(k))  # 2  P⁻ = 2 Wc_1 c² (F L)(F L)ᵀ + Q
        return UKFState(mv(F, x), P_p, None, bcast(neg, (B,)).copy())  # 2  x⁻ = F x
    chi, neg = sigma_points(x, P, w.c, method)  # 1  χ from (x⁺, P⁺)
    chi_f = propagate_f(model, chi, k)  # 1  χ* = f(χ)
    x_p, P_p, _ = ut_mean_cov(chi_f, w)  # 2  x⁻ = Σ Wm χ*, Σ Wc (χ* − x⁻)(·)ᵀ
    return UKFState(x_p, sym(P_p + model.Q(k)), chi_f, neg.copy())  # 2  + Q


def ukf_measurement_prediction(
    model: Model,
    state: UKFState,
    k: int,
    w: UTWeights,
    resample: str = "redraw",
    method: str = "svd",
    symmetric: bool = False,
) -> MeasPred:
    """§1.3 steps 3–6: sigma points (redrawn from (x⁻, P⁻), or the propagated χ*), Y = h(χ), ẑ⁻, A, Pxy.

    For a linear h with redrawn sigma points χ = x⁻ ± c·L_j the transform is again in closed form
    (see :func:`ukf_time_update`): Y_i − ẑ⁻ = ±c·H L_j, ẑ⁻ = H x⁻, A = 2·Wc_1·c² (H L)(H L)ᵀ,
    Pxy = 2·Wc_1·c² L (H L)ᵀ.
    """
    B = state.x.shape[0]
    reuse = resample == "reuse" and state.chi_f is not None
    if not reuse and getattr(model, "linear", False):
        H = model.H(state.x, k)
        L, neg = linear_sqrt(state.P, symmetric)  # 3  (redraw) χ = x⁻ ± c·L_j
        HL = H @ L
        A = w.c2 * (HL @ mT(HL))  # 5  A = Σ Wc (Y − ẑ⁻)(Y − ẑ⁻)ᵀ
        Pxy = w.c2 * (L @ mT(HL))  # 6  Pxy = Σ Wc (χ − x⁻)(Y − ẑ⁻)ᵀ
        neg = bcast(neg, (B,))
        if state.neg is not None:
            neg = neg | state.neg
        return MeasPred(mv(H, state.x), A, Pxy, neg)  # 4  ẑ⁻ = H x⁻
    if reuse:  # option: the propagated χ* (FilterPy 2.0.0 redraws instead: its predict() ends
        # by drawing σ-points from (x⁻, P⁻), which is "redraw" here, equal to it to round-off)
        chi, neg = state.chi_f, np.zeros(B, dtype=bool)
    else:
        chi, neg = sigma_points(state.x, state.P, w.c, method)  # 3  redraw from (x⁻, P⁻)
    z_hat, A, dY = ut_mean_cov(propagate_h(model, chi, k), w)  # 4–5  Y = h(χ), ẑ⁻, A
    Pxy = ut_cross(chi - state.x[:, None, :], dY, w)  # 6  Pxy
    if state.neg is not None:
        neg = neg | state.neg
    return MeasPred(z_hat, A, Pxy, neg)


def fading_update(
    x: Array,
    P: Array,
    V: Array,
    A: Array,
    Pxy: Array,
    R: Array,
    s: Array,
    sig: Array,
    form: str = "symmetric",
) -> tuple[Array, Array, Array, Array]:
    """Measurement update with state scale s (B, n) and channel factors σ (B, m) (§5 step 4).

    symmetric: P⁻' = D_x P⁻ D_x, A' = D_z A D_z, Pxy' = D_x Pxy D_z with D = diag(√·);
    literal:   P⁻' = diag(s) P⁻, A' = diag(σ) A, Pxy' = diag(s) Pxy (S2's eq. 13 style, P⁺ symmetrised).
    Then Pyy' = A' + R, K = Pxy' Pyy'⁻¹, x⁺ = x⁻ + K V, P⁺ = P⁻' − K Pyy' Kᵀ. With s = σ = 1 this
    is exactly the SVD-UKF update of §1.3 steps 6–8.

    Returns x⁺, P⁺, Pyy', fixed (B,) (Pyy' needed a numerical fix).
    """
    if form == "literal":
        P1 = s[:, :, None] * P
        A1 = sig[:, :, None] * A
        Pxy1 = s[:, :, None] * Pxy
    else:
        dx, dz = np.sqrt(s), np.sqrt(sig)
        P1 = dx[:, :, None] * P * dx[:, None, :]
        A1 = dz[:, :, None] * A * dz[:, None, :]
        Pxy1 = dx[:, :, None] * Pxy * dz[:, None, :]
    Pyy = A1 + R
    if form != "literal":
        Pyy = sym(Pyy)
    Kt, fixed = solve_sym(mT(Pyy), mT(Pxy1))  # K = Pxy' Pyy'⁻¹  (§1.3 step 7)
    x1, P2 = apply_gain(x, P1, V, Pyy, Kt)
    return x1, P2, Pyy, bcast(fixed, x.shape[:1])


def apply_gain(x: Array, P: Array, V: Array, Pyy: Array, Kt: Array) -> tuple[Array, Array]:
    """§1.3 step 8 with Kᵀ = Pyy⁻¹ Pxyᵀ given: x⁺ = x⁻ + K V, P⁺ = sym(P⁻ − K Pyy Kᵀ)."""
    K = mT(Kt)
    return x + (K @ V[..., None])[..., 0], sym(P - K @ Pyy @ Kt)


# ---------------------------------------------------------------------------------------------
# Fading factors (§5)
# ---------------------------------------------------------------------------------------------


def channel_state_map(model: Model, x: Array, k: int) -> tuple[Array, bool]:
    """Which states each channel inflates: M (m, n) or (B, m, n) bool, and whether it is exact.

    Row i of the measurement Jacobian H = ∂h/∂x selects the states channel i observes (§5: "the
    state that row i of H observes"; j(i) = i for S2's ordering [δp, δv, …] with H = [I₆ 0]). The
    closed-form scaling of A and Pxy is exact only when every row observes exactly one state
    (``exact``); otherwise the caller recomputes A', Pxy' from sigma points.
    """
    H = np.asarray(model.H(x, k), dtype=float)
    scale = np.max(np.abs(H), axis=-1, keepdims=True)
    M = np.abs(H) > 1e-12 * np.maximum(scale, 1e-300)
    return M, bool(np.all(M.sum(axis=-1) <= 1))


def fading_factors(
    V: Array,
    A: Array,
    R: Array,
    ok: Array,
    reject: Array,
    sigma_max: float,
    gate: float = 0.0,
    Pyy: Array | None = None,
) -> Array:
    """σ_i = min(σ_max, max(1, (V_i² − R_ii)/A_ii)) on rejected epochs, 1 elsewhere (§5 step 4).

    A_ii ≤ 0 or a missing channel gives σ_i = 1. ``gate`` > 0: only channels with
    |V_i|/√Pyy_ii > gate are inflated (option ``per_channel_gate``).
    """
    a = diag(A)
    r = diag(R)
    good = (a > 0) & ok & reject[:, None]
    # the division is guarded (A_ii > 0 where used); A_ii → 0⁺ or a diverged run's V may overflow
    # the ratio to inf, which the clip to σ_max below handles
    with np.errstate(over="ignore"):
        raw = np.where(good, (V**2 - r) / np.where(good, a, 1.0), 1.0)
    sig = np.clip(raw, 1.0, sigma_max)
    if gate > 0 and Pyy is not None:
        big = np.abs(V) > gate * np.sqrt(np.maximum(diag(Pyy), 1e-300))
        sig = np.where(big, sig, 1.0)
    return sig


def state_scale(sig: Array, M: Array) -> Array:
    """s_j = max over channels i observing state j of σ_i, 1 for unobserved states: (B, n)."""
    Mb = np.broadcast_to(M, (sig.shape[0], *M.shape[-2:]))
    return np.max(np.where(Mb, sig[:, :, None], 1.0), axis=1)


# ---------------------------------------------------------------------------------------------
# Filters
# ---------------------------------------------------------------------------------------------


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
        help="matrix square root of the sigma points: SVD (S2) or Cholesky (≈ 2× faster step; the "
        "same results for linear models; SVD fallback where P is not positive definite)",
    )


class _UKFBase(Filter):
    """Shared init/predict of the UKF family (the weights depend on n, fixed at init)."""

    family = "nonlinear"
    paper = "Tan, Wang, Zhao 2015 (S2), Acta Geod. Cartogr. Sin. 44(4)"

    def _weights(self, n: int) -> UTWeights:
        p = self.params
        return ut_weights(int(n), float(p.alpha_ut), float(p.beta_ut), float(p.kappa))

    def init(self, model: Model, x0: Array, P0: Array) -> Any:
        x0 = np.array(x0, dtype=float)
        self._weights(x0.shape[1])  # validates n + λ > 0 before the first step
        # every P the filter carries is symmetric bit for bit (P0 here, then the output of sym)
        return self._init_state(model, x0, sym(np.array(P0, dtype=float)))

    def _init_state(self, model: Model, x0: Array, P0: Array) -> Any:
        return UKFState(x0, P0)

    def predict(self, model: Model, state: Any, k: int) -> Any:
        w = self._weights(state.x.shape[1])
        ts = ukf_time_update(
            model,
            state.x,
            state.P,
            k,
            w,
            self.params.resample == "reuse",
            self.params.sqrt_method,
            symmetric=True,
        )
        return state._replace(x=ts.x, P=ts.P, chi_f=ts.chi_f, neg=ts.neg)

    def _predict_measurement(self, model: Model, state: Any, k: int) -> MeasPred:
        w = self._weights(state.x.shape[1])
        return ukf_measurement_prediction(
            model, state, k, w, self.params.resample, self.params.sqrt_method, symmetric=True
        )


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
        mp = self._predict_measurement(model, state, k)  # 3–6  ẑ⁻, A, Pxy
        mk = mask_missing(z, z - mp.z_hat, model.R0, U=mp.Pxy, M=mp.A)  # missing: zero gain column
        Pyy = sym(mk.M + mk.R)  # 6  Pyy = A + R
        Kt, fixed = solve_sym(mT(Pyy), mT(mk.U))  # 7  V = z − ẑ⁻, K = Pxy Pyy⁻¹
        x, P = apply_gain(state.x, state.P, mk.nu, Pyy, Kt)  # 8  x⁺ = x⁻ + K V, P⁺ = P⁻ − K Pyy Kᵀ
        flags = flag_fix(np.zeros(z.shape, dtype=np.int8), bcast(fixed, z.shape[:1]) | mp.neg)
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


class _FadingBase(_UKFBase):
    """The χ² test and the fading update shared by MFUKF and NNMFUKF."""

    def _test(self, V: Array, Pyy: Array, ok: Array, Pxy: Array) -> tuple[Array, ...]:
        """γ = Vᵀ Pyy⁻¹ V against ξ·χ²_{1−α}(available channels) (§5 steps 2–3), and the unfaded gain.

        One batched solve with the right-hand sides [V | Pxyᵀ] gives γ and Kᵀ = Pyy⁻¹ Pxyᵀ, the
        gain of every run whose fading factors turn out to be 1 (a speed trick: one LAPACK call
        instead of two; ``benchmarks/tricks.py``). Returns (γ, threshold, reject, Kᵀ, fixed).
        """
        p = self.params
        B = V.shape[0]
        X, fixed = solve_sym(Pyy, np.concatenate([V[..., None], batched(mT(Pxy), B)], axis=-1))
        gamma = np.einsum("bi,bi->b", V, X[..., 0])  # 2  γ = Vᵀ Pyy⁻¹ V
        dof = ok.sum(axis=1)
        thr = p.xi * chi2_threshold(p.alpha, np.maximum(dof, 1), V.shape[1])  # ξ ε
        reject = (gamma > thr) & (dof > 0)  # 3  γ > ξ ε: the filter is inconsistent
        return gamma, thr, reject, X[..., 1:], bcast(fixed, (B,))

    def _fade(
        self,
        model: Model,
        state: Any,
        k: int,
        V: Array,
        A: Array,
        Pxy: Array,
        R: Array,
        ok: Array,
        reject: Array,
        Pyy0: Array,
        Kt0: Array,
        fixed0: Array,
    ) -> tuple[Array, Array, Array, Array, Array]:
        """σ, s and the update of §5 steps 3–4. Returns x⁺, P⁺, Pyy', fixed, σ.

        ``Kt0``, ``fixed0``: the unfaded gain Kᵀ = Pyy0⁻¹ Pxyᵀ from :meth:`_test`. A run whose
        factors are all 1 takes it (the update with σ = s = 1 is exactly the unfaded SVD-UKF
        update, step 3); only the faded runs are solved again (step 4).
        """
        p = self.params
        B = V.shape[0]
        if not reject.any():  # 3  every run passes: σ = 1, the ordinary SVD-UKF update
            x, P = apply_gain(state.x, state.P, V, Pyy0, Kt0)
            return x, P, batched(Pyy0, B), fixed0, np.ones_like(V)
        sig = fading_factors(V, A, R, ok, reject, p.sigma_max, p.per_channel_gate, Pyy0)  # 4  σ_i
        M, exact = channel_state_map(model, state.x, k)
        s = state_scale(sig, M)  # 4  s_j = σ_i(j)
        if (p.recompute_sigma or not exact) and np.any(sig > 1.0):
            # exact for any h: sigma points of (x⁻, P⁻') give A', Pxy'; then an unscaled update
            dx = np.sqrt(s)
            P1 = dx[:, :, None] * state.P * dx[:, None, :]
            w = self._weights(state.x.shape[1])
            mp = ukf_measurement_prediction(model, UKFState(state.x, P1), k, w, "redraw", p.sqrt_method)
            mk = mask_missing(np.where(ok, 0.0, np.nan), V, U=mp.Pxy, M=mp.A)
            one_n, one_m = np.ones_like(s), np.ones_like(sig)
            x, P, Pyy, fixed = fading_update(state.x, P1, V, mk.M, mk.U, R, one_n, one_m)
            return x, P, Pyy, fixed | mp.neg, sig
        fade = np.any(sig != 1.0, axis=1) | np.any(s != 1.0, axis=1)
        if fade.all():  # 4  every run fades
            x, P, Pyy, fixed = fading_update(state.x, state.P, V, A, Pxy, R, s, sig, p.form)
            return x, P, Pyy, fixed, sig
        # the runs that do not fade: the unfaded gain (step 3); the faded ones (a subset): step 4
        x, P = apply_gain(state.x, state.P, V, Pyy0, Kt0)
        Pyy, fixed = batched(Pyy0, B), fixed0
        if fade.any():
            i = np.flatnonzero(fade)
            xf, Pf, Pyyf, fixf = fading_update(
                state.x[i],
                batched(state.P, B)[i],
                V[i],
                batched(A, B)[i],
                batched(Pxy, B)[i],
                batched(R, B)[i],
                s[i],
                sig[i],
                p.form,
            )
            x, P, Pyy, fixed = x.copy(), batched(P, B).copy(), Pyy.copy(), fixed.copy()
            x[i], P[i], Pyy[i], fixed[i] = xf, Pf, Pyyf, fixf
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
        mp = self._predict_measurement(model, state, k)
        V = z - mp.z_hat
        mk = mask_missing(z, V, model.R0, U=mp.Pxy, M=mp.A)  # missing channels: zero gain column
        ok, V, A, Pxy, R = mk.ok, mk.nu, mk.M, mk.U, mk.R
        Pyy0 = sym(A + R)  # Pyy = A + R
        gamma, thr, reject, Kt0, fixed0 = self._test(V, Pyy0, ok, Pxy)  # 2–3
        x, P, Pyy, fixed, sig = self._fade(model, state, k, V, A, Pxy, R, ok, reject, Pyy0, Kt0, fixed0)
        flags = np.zeros(z.shape, dtype=np.int8)
        flags[reject[:, None] & ok] = EPOCH_ANOMALY  # flag 5 on every channel of a rejected epoch
        flag_fix(flags, fixed | mp.neg)
        stats = {"gamma": gamma, "gamma_threshold": thr, "fading": sig, "rejected": reject.astype(float)}
        out = StepOut(x=x, P=P, innov=V, S=Pyy, R_used=R, flags=flags, stats=stats)
        return UKFState(x, P), out
