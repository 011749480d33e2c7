"""Huber, variational-Bayes and Student-t filters of the HAKF paper (Zuo et al. 2017) family.

* ``huber-kf``  — Huber M-estimation by re-weighted R (HKF, ALGORITHMS.md §2, S0 eqs. 7–10);
* ``vb-akf``    — Särkkä–Nummenmaa variational-Bayes adaptive R (AKF, §3.1);
* ``hakf``      — VB adaptive R + Huber re-weighting inside the VB loop (HAKF, §3.2, S0 eqs. 11–21);
* ``student-t-kf`` — VB Student-t measurement-noise KF (§1.6).

Implementation note (speed, exactness). Every VB iteration restarts from the PRIOR (x⁻, P⁻) and
only the diagonal R changes between iterations, so the iterations are done in measurement space:
with M = H P⁻ Hᵀ and S = M + R̃,

    z − H x^(it+1) = R̃ S⁻¹ ν ,        H P^(it+1) Hᵀ = M − M S⁻¹ M

(algebraically identical to forming K, x and P each time). The n×n gain, mean and Joseph-form
covariance are formed once, with the R̃ of the last iteration (the R in the last gain, §3.1).
For the optimal gain the Joseph form equals the paper's (I − K H) P⁻ (eq. 20).

Iterations: at most N (``iters``, default 10, §3.1). A run stops early once its β changes by less
than ``tol`` (relative, default 1e-6; ``tol = 0`` runs exactly N as the spec states); frozen runs
keep the β, R̃ and weights of their last iteration, so a run's numbers never depend on the rest
of its batch. ``stats["vb_iters"]`` is the per-run iteration count, ``stats["vb_delta"]`` the last
relative change. On the sins-gps scenario the VB filters stop after ≈ 4–5 iterations on average,
and the result differs from N = 10 by < 1e-6 of a state σ.

References
----------
Y. Zuo, W. Yin, J. Gao, K. Li, "Adaptive robust filtering algorithm based on variational
Bayesian", Navigation Positioning and Timing 4(5), 2017, doi:10.19306/j.cnki.2095-8110.2017.05.008.
S. Särkkä, A. Nummenmaa, "Recursive noise adaptive Kalman filtering by variational Bayesian
approximations", IEEE Trans. Automatic Control 54(3):596–600, 2009, doi:10.1109/TAC.2008.2008348.
P. J. Huber, "Robust estimation of a location parameter", Ann. Math. Statist. 35(1), 1964.
R. Piché, S. Särkkä, J. Hartikainen, "Recursive outlier-robust filtering and smoothing for
nonlinear systems using the multivariate Student-t distribution", IEEE MLSP 2012,
doi:10.1109/MLSP.2012.6349794.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from navlab.errors import NavlabError
from navlab.filters.base import (
    DOWNWEIGHTED,
    NUMERICAL_FIX,
    Filter,
    KFState,
    Model,
    SideInfo,
    StepOut,
    register,
)
from navlab.linalg import (
    Array,
    PHt,
    bcast,
    cofactor_index,
    diag,
    diag_embed,
    joseph_from_gain,
    kf_gain,
    mask_missing,
    mT,
    mv,
    solve_sym,
    sym,
)
from navlab.params import param

__all__ = ["HAKF", "VBAKF", "HuberKF", "StudentTKF", "huber_weight"]

_GAMMA_HELP = "Huber threshold γ_H on the normalised residual (1.345: 95 % Gaussian efficiency)"
_RHO_DEFAULT = 1.0 - math.exp(-4.0)  # ≈ 0.9817, memory 1/(1−ρ) ≈ 55 epochs (§3.1, §10 #8)


def huber_weight(e: Array, gamma: float) -> Array:
    """Huber weight ψ_H(e)/e: 1 where |e| < γ, γ/|e| otherwise (w(0) := 1). S0 eqs. 8–9."""
    return gamma / np.maximum(np.abs(e), gamma)  # exactly 1.0 where |e| ≤ γ


def _rowmax(a: Array) -> Array:
    """Max over the last axis of (B, m); for m ≤ 2 without a reduction (≈ 5× less overhead)."""
    m = a.shape[-1]
    if m == 1:
        return a[:, 0]
    return np.maximum(a[:, 0], a[:, 1]) if m == 2 else a.max(axis=-1)


def _rowsum(a: Array) -> Array:
    """Sum over the last axis of (B, m); for m ≤ 2 without a reduction."""
    m = a.shape[-1]
    if m == 1:
        return a[:, 0]
    return a[:, 0] + a[:, 1] if m == 2 else a.sum(axis=-1)


class _MeasSpace:
    """The VB/IRLS iterations in measurement space for a fixed prior (M = H P⁻ Hᵀ, ν).

    ``step(R̃)`` returns, for S = M + diag(R̃) (R̃ (B, m) diagonal, > 0): the posterior residual
    z − H x⁺ = R̃ S⁻¹ ν and diag(H P⁺ Hᵀ) = diag(M − M S⁻¹ M). Everything that does not change
    between iterations is formed once, and for m ≤ 3 S⁻¹ is the closed-form adjugate/det (for
    m ≤ 2 element by element): Python overhead, not arithmetic, dominates these tiny problems (a
    LAPACK call per iteration cost ≈ 3× more). S is SPD (M ⪰ 0, R̃ > 0); for m > 3 ``ill``
    records an S that needed jitter; the final gain is formed by :func:`_finish`, which checks
    the final S itself.
    """

    def __init__(self, M: Array, nu: Array) -> None:
        B, m = nu.shape
        self.B, self.m = B, m
        self.Mb = bcast(M, (B, m, m))
        self.dM = diag(self.Mb).copy()
        self.ill = np.zeros(B, dtype=bool)
        if m <= 2:
            # S = [[d0 + r0, b], [b, d1 + r1]] element by element: a dozen (B, 2) operations per
            # step, no matrix products or reductions (each costs several small operations' worth)
            b = self.Mb[:, 0, 1:] if m == 2 else np.zeros((B, 1))  # (B, 1)
            self.b2 = b * b
            self.nu = nu
            self.c = b * nu[:, ::-1]  # adj(S)ν = (d1 + r1, d0 + r0)·ν − b·(ν1, ν0)
            # diag(M adj(S) M)_i = M_i0² (d1+r1) + M_i1² (d0+r0) − 2 b² M_ii (M symmetric)
            self.A1 = np.concatenate([self.dM[:, :1] ** 2, self.b2], axis=1)
            self.A0 = np.concatenate([self.b2, self.dM[:, 1:] ** 2], axis=1)
            self.C = 2.0 * self.b2 * self.dM
            return
        self.rhs = np.concatenate([nu[..., None], self.Mb], axis=-1)
        self.Mf = np.ascontiguousarray(self.Mb).reshape(B, m * m)
        self.E = np.eye(m * m)[:: m + 1]  # (m, m²): diagonal entries of a flattened matrix
        if m == 3:
            # S⁻¹ν = C ν / det and diag(M S⁻¹ M)_i = Σ_jk C_jk M_ij M_ik / det with the cofactor
            # matrix C (symmetric S): flattened products, no stacked matmul per iteration
            self.idx, _ = cofactor_index(m)
            self.nu_f = np.tile(nu, (1, m))[:, np.arange(m * m).reshape(m, m)]  # (B, m, m): ν_k
            self.MM = (self.Mb[:, :, :, None] * self.Mb[:, :, None, :]).reshape(B, m, m * m)

    def step(self, Rt: Array) -> tuple[Array, Array]:
        B, m = self.B, self.m
        if m == 1:
            inv = 1.0 / (self.dM + Rt)
            return Rt * self.nu * inv, self.dM - self.dM * self.dM * inv
        if m == 2:
            Sd = self.dM + Rt
            inv = 1.0 / (Sd[:, :1] * Sd[:, 1:] - self.b2)  # 1/det S, (B, 1)
            resid = Rt * (Sd[:, ::-1] * self.nu - self.c) * inv
            return resid, self.dM - (self.A1 * Sd[:, 1:] + self.A0 * Sd[:, :1] - self.C) * inv
        if m > 3:
            S = self.Mb + diag_embed(Rt)
            X, fixed = solve_sym(S, self.rhs)
            self.ill |= fixed
            return Rt * X[..., 0], self.dM - np.einsum("bij,bji->bi", self.Mb, X[..., 1:])
        Sf = self.Mf + Rt @ self.E
        G = Sf[:, self.idx]
        cof = G[:, 0:9] * G[:, 9:18] - G[:, 18:27] * G[:, 27:36]
        det = np.einsum("bi,bi->b", Sf[:, :m], cof[:, :m])
        inv = (1.0 / det)[:, None]
        Snu = np.einsum("bij,bij->bi", cof.reshape(B, m, m), self.nu_f)  # adj(S) ν
        resid = Rt * Snu * inv
        hph = self.dM - np.einsum("bij,bj->bi", self.MM, cof) * inv
        return resid, hph


def _finish(model: Model, x: Array, P: Array, H: Array, nu: Array, R_used: Array):
    """Gain, mean and Joseph covariance with the final (B, m, m) R_used (§0.2 rules 1–3).

    With U = P⁻Hᵀ and S = H U + R the Joseph form (I−KH)P⁻(I−KH)ᵀ + K R Kᵀ is evaluated as its
    exact expansion P⁻ − K Uᵀ − U Kᵀ + K S Kᵀ (valid for any gain K): only n×m and m×n
    products instead of three n×n×n ones per run, the dominant cost on 15-state models.
    S⁻¹ is the closed-form inverse for m ≤ 3 (LU solve otherwise or when S is ill-conditioned).
    """
    B, m = nu.shape
    U, HU = PHt(P, H)  # (B, n, m), (B, m, m)
    S = sym(bcast(HU + R_used, (B, m, m)))
    K, fixed = kf_gain(U, S)
    P_post = joseph_from_gain(P, K, U, S)
    return x + mv(K, nu), P_post, S, fixed


def _flags(down: Array, fixed: Array) -> Array:
    flags = np.where(down, DOWNWEIGHTED, 0).astype(np.int8)
    if np.any(fixed):
        flags[np.broadcast_to(fixed, flags.shape[:1])] = NUMERICAL_FIX
    return flags


# ---------------------------------------------------------------------------------------------
# Huber KF (§2)


@dataclass(frozen=True)
class HuberParams:
    """Huber KF options (ALGORITHMS.md §2)."""

    gamma: float = param(1.345, lo=0.1, hi=1e12, help=_GAMMA_HELP)
    normalize: str = param(
        "R",
        choices=("R", "S"),
        help="normalise the innovation by R (paper, S0 eq. 16 form) or by S = HP⁻Hᵀ + R",
    )
    irls_iters: int = param(
        1,
        lo=1,
        hi=50,
        help="passes; >1 recomputes the residual from the posterior z − Hx⁺ (IRLS reading)",
    )


@register
class HuberKF(Filter):
    """Huber robust KF by channel-wise re-weighted R (HKF; ALGORITHMS.md §2, S0 eqs. 7–10).

    Per pass: e = L⁻¹ ν (R0 = L Lᵀ), w_j = ψ_H(e_j)/e_j, R̃ = L Ψ⁻¹ Lᵀ (the consistent form of
    S0 eq. 10, identical to it for diagonal R), then a KF update with R̃ (Joseph form).
    """

    key = "huber-kf"
    label = "HKF (Huber)"
    family = "robust"
    paper = "Zuo et al. 2017 (HAKF paper), eqs. 7–10"
    spec_section = "§2"
    summary = "Huber M-estimation: inflates R on channels whose normalised residual exceeds γ."
    Params = HuberParams

    def update(self, model: Model, state: KFState, k: int, z: Array, side: SideInfo):
        p = self.params
        x0, P0 = state.x, state.P
        H = model.H(x0, k)
        nu = z - model.h(x0, k)
        R0 = np.asarray(model.R0, dtype=float)
        r0 = np.diagonal(R0)
        diagonal = bool(np.all(np.diag(r0) == R0))
        L = np.diag(np.sqrt(r0)) if diagonal else np.linalg.cholesky(R0)
        ok, nu_m, H_m, _ = mask_missing(z, nu, H, R0)
        all_ok = bool(ok.all())
        r = nu_m  # residual the weights are computed from (prior innovation on pass 1)
        for _ in range(p.irls_iters):
            # (16) e = R^{-1/2}(z − H x); option "S": ν̃_i = r_i / sqrt(S_ii), S from R0
            if p.normalize == "S":
                e = r / np.sqrt(diag(H_m @ P0 @ mT(H_m)) + r0)
            elif diagonal:
                e = r / np.sqrt(r0)
            else:
                e = np.linalg.solve(L, r.T).T
            w = huber_weight(e, p.gamma)  # (9) Ψ = diag(ψ(e)/e)
            if not all_ok:
                w = np.where(ok, w, 1.0)
            # (10) R̃ = L Ψ⁻¹ Lᵀ (for diagonal R0: R0_jj / w_j)
            Rt = diag_embed(r0 / w) if diagonal else (L / w[:, None, :]) @ L.T
            _, _, H_u, Rt_m = mask_missing(z, nu, H, Rt)
            x, P, S, fixed = _finish(model, x0, P0, H_u, nu_m, Rt_m)
            if p.irls_iters > 1:
                r = np.where(ok, z - model.h(x, k), 0.0)
        out = StepOut(
            x=x,
            P=P,
            innov=nu_m,
            S=S,
            R_used=Rt_m,
            weights=w,
            flags=_flags(w < 1.0, fixed),
            stats={"huber_passes": np.full(z.shape[0], float(p.irls_iters))},
        )
        return KFState(x, P), out


# ---------------------------------------------------------------------------------------------
# VB adaptive KF (§3.1) and HAKF (§3.2)


class VBState(NamedTuple):
    """Mean, covariance and the per-channel inverse-gamma parameters α, β (B, m)."""

    x: Array
    P: Array
    alpha: Array
    beta: Array


@dataclass(frozen=True)
class VBParams:
    """Variational-Bayes adaptive KF options (ALGORITHMS.md §3.1)."""

    rho: float = param(
        _RHO_DEFAULT,
        lo=1e-3,
        hi=1.0,
        help="forgetting factor ρ of α, β (1 = stationary R; 1 − e⁻⁴ ≈ 0.982: memory ≈ 55 epochs)",
    )
    iters: int = param(10, lo=1, hi=100, help="VB iterations N per epoch")
    alpha0: float = param(
        1.0,
        lo=1e-3,
        hi=1e15,
        help="prior shape α₀ (β₀ = α₀·R0_ii); larger = stronger prior on the nominal R",
    )
    adapt: bool = param(True, help="estimate R; off = R̂ fixed at the nominal R0 (then a plain KF)")
    tol: float = param(
        1e-6,
        lo=0.0,
        hi=1.0,
        help="stop before N iterations once max |Δβ/β| < tol in every run (0: always exactly N)",
    )


class _VBBase(Filter):
    """Shared machinery of ``vb-akf`` and ``hakf`` (S0 eqs. 11–21 with/without the Huber lines)."""

    estimates_R = True
    huber = False

    def init(self, model: Model, x0: Array, P0: Array) -> VBState:
        x0 = np.array(x0, dtype=float)
        B = x0.shape[0]
        R0 = np.asarray(model.R0, dtype=float)
        R0d = np.diagonal(R0)
        if np.any(np.diag(R0d) != R0):
            raise NavlabError(
                f"filter '{self.key}' estimates a DIAGONAL R (§3.1); this scenario's nominal R "
                "has correlated channels: choose another filter or independent channels"
            )
        alpha = np.full((B, R0d.size), float(self.params.alpha0))
        return VBState(x0, np.array(P0, dtype=float), alpha, alpha * R0d)

    def predict(self, model: Model, state: VBState, k: int) -> VBState:
        st = super().predict(model, state, k)  # (11)–(12) x⁻ = F x⁺ ; P⁻ = F P⁺ Fᵀ + Q
        if not self.params.adapt:
            return st
        rho = self.params.rho
        return st._replace(alpha=rho * st.alpha, beta=rho * st.beta)  # (13)–(14)

    def _weights(self, e: Array) -> Array:
        return np.ones_like(e)

    def update(self, model: Model, state: VBState, k: int, z: Array, side: SideInfo):
        p = self.params
        x0, P0 = state.x, state.P
        H = model.H(x0, k)
        nu = z - model.h(x0, k)
        R0 = np.asarray(model.R0, dtype=float)
        ok, nu, H, _ = mask_missing(z, nu, H, R0)
        all_ok = bool(ok.all())
        ms = _MeasSpace(PHt(P0, H)[1], nu)
        beta_minus = state.beta
        alpha = state.alpha + 0.5 * ok if p.adapt else state.alpha  # α = α⁻ + 1/2 (kept over it)
        beta = beta_minus
        B = z.shape[0]
        prev_resid = nu
        # per-run convergence: a run whose β changed by < tol is frozen (its β, R̃ and weights
        # are those of its last iteration), so a run's result never depends on its batch
        active = np.ones(B, dtype=bool)
        iters = np.zeros(B)
        delta = np.zeros(B)
        Rt_last = w_last = None
        all_active = True  # fast path: no np.where while every run is still iterating
        w = np.ones_like(nu)
        for it in range(p.iters):
            Rhat = beta / alpha  # (15) R̂^(it) = diag(β^(it)/α)
            if self.huber:
                r_e = prev_resid if (p.irls and it > 0) else nu
                w = self._weights(r_e / np.sqrt(Rhat))  # (16) e = R̂^{-1/2}(z − H x⁻); (9)
                if not all_ok:
                    w = np.where(ok, w, 1.0)
            Rt = Rhat / w if self.huber else Rhat  # (17) R̃ = R̂^{1/2} Ψ⁻¹ R̂^{1/2} (diagonal)
            if not all_ok:
                Rt = np.where(ok, Rt, 1.0)
            resid, hph = ms.step(Rt)  # (18)–(20) in measurement space
            if all_active:
                iters += 1.0
                Rt_last, w_last = Rt, w
            else:
                iters += active
                Rt_last = np.where(active[:, None], Rt, Rt_last)
                w_last = np.where(active[:, None], w, w_last)
            if not p.adapt:
                break
            r2 = resid * resid
            if self.huber and p.robust_beta:  # navlab extension (off by default, §3.2)
                r2 = r2 * self._weights(resid / np.sqrt(Rhat))
            beta_new = beta_minus + 0.5 * (r2 + hph)  # (21)
            if not all_ok:
                beta_new = np.where(ok, beta_new, beta_minus)
            d = _rowmax(np.abs(beta_new - beta) / beta)
            if all_active:
                delta, beta = d, beta_new
            else:
                delta = np.where(active, d, delta)
                beta = np.where(active[:, None], beta_new, beta)
            prev_resid = resid
            if p.tol > 0:
                active &= d >= p.tol
                n_active = np.count_nonzero(active)
                all_active = n_active == B
                if n_active == 0:
                    break
        Rt, w = Rt_last, w_last
        any_fixed = ms.ill  # (m > 3 only; for m ≤ 3 _finish checks the final S)
        R_used = diag_embed(Rt)  # the R in the last gain (R̃^(N−1))
        _, _, H_u, R_used = mask_missing(z, nu, H, R_used)
        x, P, S, fixed = _finish(model, x0, P0, H_u, nu, R_used)
        any_fixed |= fixed
        R_hat = diag_embed(beta / alpha)  # R̂ = diag(β^(N)/α)  (β/α, not the IG mean; §3.1 a)
        stats = {
            "vb_iters": iters,
            "vb_delta": delta,
            "alpha": alpha.copy(),
        }
        out = StepOut(
            x=x,
            P=P,
            innov=nu,
            S=S,
            R_used=R_used,
            R_hat=R_hat,
            weights=w,
            flags=_flags(w < 1.0, any_fixed),
            stats=stats,
        )
        return VBState(x, P, alpha, beta), out


@register
class VBAKF(_VBBase):
    """Variational-Bayes adaptive KF of Särkkä & Nummenmaa 2009 (AKF; ALGORITHMS.md §3.1).

    Gaussian × product-of-inverse-gamma posterior over (x_k, diag R_k); forgetting ρ on α, β;
    N fixed-point iterations per epoch, each from the prior (S0 eqs. 11–15, 18–21).
    """

    key = "vb-akf"
    label = "AKF (VB)"
    family = "adaptive"
    paper = "Särkkä & Nummenmaa 2009 (comparator AKF of Zuo et al. 2017)"
    spec_section = "§3.1"
    summary = "Variational Bayes: estimates a slowly varying diagonal R (inverse-gamma posteriors)."
    Params = VBParams


@dataclass(frozen=True)
class HAKFParams(VBParams):
    """HAKF options (ALGORITHMS.md §3.2): the AKF's plus the Huber threshold and two extensions."""

    gamma: float = param(1.345, lo=0.1, hi=1e12, help=_GAMMA_HELP)
    robust_beta: bool = param(
        False,
        help="navlab extension (not in the paper): Huber-weight the residual fed to β (eq. 21)",
    )
    irls: bool = param(
        False,
        help="use the posterior residual z − Hx^(it) in eq. 16 for it ≥ 1 (Gauss–Newton reading)",
    )


@register
class HAKF(_VBBase):
    """VB adaptive R with Huber re-weighting inside the VB loop (Zuo et al. 2017; §3.2).

    Each iteration: R̂ = β/α (15), e = R̂^{-1/2} ν from the prior innovation (16), Huber weights
    (9), R̃ = R̂/w (17), KF update from the prior with R̃ (18)–(20), β from the raw posterior
    residual (21) — so β absorbs part of every outlier, as in the paper (option ``robust_beta``).
    """

    key = "hakf"
    label = "HAKF (VB + Huber)"
    family = "robust-adaptive"
    paper = "Zuo, Yin, Gao, Li 2017, Navigation Positioning and Timing 4(5)"
    spec_section = "§3.2"
    summary = "The HAKF paper's filter: VB tracks a time-varying R, Huber down-weights outliers."
    Params = HAKFParams
    huber = True

    def _weights(self, e: Array) -> Array:
        return huber_weight(e, self.params.gamma)


# ---------------------------------------------------------------------------------------------
# Student-t VB KF (§1.6)


@dataclass(frozen=True)
class StudentTParams:
    """Student-t VB KF options (ALGORITHMS.md §1.6)."""

    dof: float = param(5.0, lo=0.1, hi=1e15, help="degrees of freedom ν_t of the noise (∞: the Gaussian KF)")
    iters: int = param(5, lo=1, hi=100, help="VB iterations N_t per epoch")
    flag_below: float = param(
        0.5, lo=0.0, hi=1.0, help="flag the epoch as down-weighted when λ̄ is below this"
    )


@register
class StudentTKF(Filter):
    """VB Student-t KF: R_eff = R0/λ̄ with λ̄ = (ν+m)/(ν + tr(D R0⁻¹)) iterated (§1.6).

    D = (z − H x⁺)(z − H x⁺)ᵀ + H P⁺ Hᵀ; λ̄ ≪ 1 marks an outlier epoch (whole-vector scaling).
    """

    key = "student-t-kf"
    label = "Student-t VB KF"
    family = "robust"
    paper = "Piché, Särkkä, Hartikainen 2012 (baseline; not in the seed papers)"
    spec_section = "§1.6"
    summary = "Heavy-tailed (Student-t) measurement noise by variational Bayes: scales R per epoch."
    Params = StudentTParams

    def update(self, model: Model, state: KFState, k: int, z: Array, side: SideInfo):
        p = self.params
        x0, P0 = state.x, state.P
        H = model.H(x0, k)
        nu = z - model.h(x0, k)
        R0 = np.asarray(model.R0, dtype=float)
        ok, nu, H, R0m = mask_missing(z, nu, H, R0)
        B, m = nu.shape
        dof_m = np.count_nonzero(ok, axis=1).astype(float)
        # iterate whitened by R0 = L Lᵀ: then R_eff = I/λ is diagonal, so the iterations run in
        # measurement space (_MeasSpace) and tr(D R0⁻¹) = |L⁻¹(z − H x⁺)|² + tr(L⁻¹ H P⁺ Hᵀ L⁻ᵀ)
        M = PHt(P0, H)[1]
        r0 = np.diagonal(R0)
        if R0m is R0 and np.array_equal(np.diag(r0), R0):  # every channel, independent: scale
            li = 1.0 / np.sqrt(r0)
            ms = _MeasSpace(M * (li[:, None] * li), nu * li)
        else:
            Li = np.linalg.inv(np.linalg.cholesky(R0m))
            ms = _MeasSpace(Li @ M @ mT(Li), mv(Li, nu))  # missing channels: zero rows stay zero
        lam = np.ones(B)
        ones = np.ones(m)
        for _ in range(p.iters):
            resid, hph = ms.step(ones / lam[:, None])  # whitened z − H x⁺ and diag H P⁺ Hᵀ
            tr = np.maximum(_rowsum(resid * resid + hph), 0.0)  # missing channels add 0
            lam = (p.dof + dof_m) / (p.dof + tr)
        any_fixed = ms.ill
        Reff = R0m / lam[:, None, None]
        x, P, S, fixed = _finish(model, x0, P0, H, nu, Reff)
        any_fixed |= fixed
        w = np.where(ok, lam[:, None], 1.0) * np.ones((B, m))
        down = (lam < p.flag_below)[:, None] & ok
        out = StepOut(
            x=x,
            P=P,
            innov=nu,
            S=S,
            R_used=bcast(Reff, (B, m, m)),
            weights=w,
            flags=_flags(down, any_fixed),
            stats={"lambda": lam},
        )
        return KFState(x, P), out
