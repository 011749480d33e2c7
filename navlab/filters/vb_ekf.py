"""Variational-Bayes EKF with inverse-Wishart P_{k|k−1} and R (ALGORITHMS.md §7).

Huang et al. 2018 (IEEE TAC) as applied with EKF linearisation by Hou et al. 2024 (Algorithm 1).
The joint posterior of the state, the one-step prediction covariance P_{k|k−1} and a full
measurement-noise covariance R_k is approximated by N(x) · IW(P_{k|k−1}; t, T) · IW(R_k; u, U) and
refined by N fixed-point iterations::

    time update      x⁻ = f(x⁺) ;  P̃⁻ = A P⁺ Aᵀ + Q̃                           (nominal Q̃)
    initialise       x⁽⁰⁾ = x⁻ ;  P⁽⁰⁾ = P̃⁻ ;  t⁻ = n + τ_P + 1 ;  T⁻ = τ_P P̃⁻
                     u⁻ = ρ (û − m − 1) + m + 1 ;  U⁻ = ρ Û                    (S3 eq. 14)
    for it = 0 … N−1:
        A_P = P⁽ⁱᵗ⁾ + (x⁽ⁱᵗ⁾ − x⁻)(x⁽ⁱᵗ⁾ − x⁻)ᵀ ;  t = t⁻ + 1 ;  T = T⁻ + A_P
        r = z − h(x⁽ⁱᵗ⁾) ;  B_R = r rᵀ + H P⁽ⁱᵗ⁾ Hᵀ ;  u = u⁻ + 1 ;  U = U⁻ + B_R
        P̂ = T / (t − n − 1) ;  R̂ = U / (u − m − 1)
        K = P̂ Hᵀ (H P̂ Hᵀ + R̂)⁻¹
        x⁽ⁱᵗ⁺¹⁾ = x⁻ + K (z − h(x⁻)) ;  P⁽ⁱᵗ⁺¹⁾ = P̂ − K H P̂   (Joseph form, same value)
    x⁺ = x⁽ᴺ⁾ ;  P⁺ = P⁽ᴺ⁾ ;  (û, Û) = (u, U)

Notes (ALGORITHMS.md §7):

* P̂ = T/(t − n − 1) and R̂ = U/(u − m − 1) are the inverse-Wishart MEANS E[P], E[R]; Huang (and
  S3's "E[R⁻¹] = (u − d − 1) U⁻¹") use {E[R]}⁻¹ where exact VB would use E[R⁻¹] = u U⁻¹. navlab
  reproduces Huang exactly: at the prior P̂ = P̃⁻ and R̂ = R̃₀.
* The state update uses the PRIOR innovation z − h(x⁻) while the R-part uses z − h(x⁽ⁱᵗ⁾): that
  is Huang's algorithm (q(x) is the exact posterior given P̂, R̂), not an iterated EKF. H is the
  Jacobian at x⁻, kept fixed in the loop.
* S3's typos ``f(x̂, ρ)``, ``h(x̂ | ρ)`` read f(x̂), h(x̂); its single τ ("π" in the input list)
  is split into τ_P (P-prior, re-set every epoch) and τ_R (initial R-prior, used once), as in
  Huang's code. Initial R-distribution û₀ = m + 1 + τ_R, Û₀ = τ_R R̃₀ (so R̂ starts at R̃₀).
* Missing channels (NaN in z): the gain column is zero (as in the KF) and the R-statistic of the
  missing noise is its conditional expectation given the observed channels under the current
  E[R] (``_fill_missing``; positive semidefinite), so R̂ of a channel that is not observed and
  not correlated with the others stays where it was (E over the missing residual, not a silent
  shrink).

References
----------
Y. Huang, Y. Zhang, Z. Wu, N. Li, J. Chambers, "A novel adaptive Kalman filter with inaccurate
process and measurement noise covariance matrices", IEEE Trans. Automatic Control 63(2), 594–601,
2018, doi:10.1109/TAC.2017.2730480.
Hou H., Cheng M., Huang D., Guo S., Wang T., "GPS/INS loose integrated navigation and positioning
algorithm based on VB-EKF", Computer Applications and Software 41(6), 2024,
doi:10.3969/j.issn.1000-386x.2024.06.041.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from navlab.filters.base import (
    Filter,
    KFLimit,
    Model,
    SideInfo,
    StepOut,
    Teaching,
    flag_fix,
    register,
)
from navlab.filters.ekf import ekf_predict
from navlab.linalg import Array, joseph_from_gain, mask_missing, mT, mv, solve_sym, sym
from navlab.params import param


class VBState(NamedTuple):
    """Per-run VB-EKF state: posterior (x, P) and the inverse-Wishart R-distribution (u, U).

    u is the same in every run (its recursion does not depend on data): a float. U is (B, m, m).
    """

    x: Array
    P: Array
    u: float
    U: Array


@dataclass(frozen=True)
class VBEKFParams:
    """VB-EKF hyper-parameters (ALGORITHMS.md §7, §10 #35–#36)."""

    tau_P: float = param(
        10.0,
        lo=1e-3,
        hi=1e12,
        help="prior weight τ_P of the P_{k|k−1} inverse-Wishart (navlab default 10; Huang: 3; "
        "large = trust the nominal Q)",
    )
    tau_R: float = param(
        3.0,
        lo=1e-3,
        hi=1e12,
        help="prior weight τ_R of the initial R inverse-Wishart (Huang: 3; large = trust R0)",
    )
    rho: float = param(
        1.0 - math.exp(-4.0),
        lo=0.01,
        hi=1.0,
        help="forgetting factor ρ of the R-distribution (1 − e⁻⁴ ≈ 0.982: memory ≈ 55 epochs; "
        "1 = constant R)",
    )
    iterations: int = param(10, lo=1, hi=100, help="VB fixed-point iterations N per epoch")
    tol: float = param(
        0.0,
        lo=0.0,
        hi=1.0,
        help="stop a run's iterations when its state change is below tol × its correction "
        "(0 = always N, as in the paper)",
    )
    adapt_P: bool = param(
        True, help="estimate P_{k|k−1} too (Huang); off = R-only VB with the nominal P_{k|k−1}"
    )


@register
class VBEKF(Filter):
    """VB-EKF: EKF with variational inverse-Wishart estimates of P_{k|k−1} and R (§7)."""

    key = "vb-ekf"
    label = "VB-EKF"
    family = "adaptive"
    paper = "Hou et al. 2024; Huang et al. 2018 (IEEE TAC)"
    spec_section = "§7"
    summary = (
        "Learns a full measurement-noise covariance R (and the prediction covariance P) on line "
        "with variational-Bayes inverse-Wishart updates; forgets old noise with factor ρ."
    )
    estimates_R = True
    Params = VBEKFParams
    kf_limit = KFLimit(
        {"adapt_P": False, "tau_R": 1e12, "rho": 1.0},
        why="the nominal P⁻ and an R-prior of weight τ_R → ∞ without forgetting keep R̂ = R0: the EKF",
    )
    teaching = Teaching(
        idea=(
            "Huang et al.'s VB filter (applied by Hou et al. 2024 to GPS/INS): both the predicted "
            "covariance P⁻ and a full R get inverse-Wishart distributions, refined by a fixed-point "
            "loop; a wrong Q is absorbed by P̂, a changing noise level by R̂. The prior weights τ_P "
            "and τ_R decide which of the two absorbs a sudden change."
        ),
        equations=(
            r"t^- = n + \tau_P + 1,\ T^- = \tau_P \tilde P^-; \qquad "
            r"u^- = \rho(\hat u_{k-1} - m - 1) + m + 1,\ U^- = \rho\,\hat U_{k-1}",
            r"T = T^- + P^{(it)} + (x^{(it)} - x^-)(x^{(it)} - x^-)^\top, \qquad t = t^- + 1",
            r"U = U^- + r r^\top + H P^{(it)} H^\top,\ r = z - h(x^{(it)}), \qquad u = u^- + 1",
            r"\hat P = T/(t - n - 1), \qquad \hat R = U/(u - m - 1)",
            r"K = \hat P H^\top(H\hat P H^\top + \hat R)^{-1}, \quad "
            r"x^{(it+1)} = x^- + K(z - h(x^-)), \quad P^{(it+1)} = \hat P - K H \hat P",
        ),
    )

    def init(self, model: Model, x0: Array, P0: Array) -> VBState:
        p = self.params
        m = model.m
        x = np.array(x0, dtype=float)
        # û₀ = m + 1 + τ_R, Û₀ = τ_R R̃₀  ⇒  R̂ = Û₀/(û₀ − m − 1) = R̃₀  (§10 #36)
        U = np.broadcast_to(p.tau_R * np.asarray(model.R0, float), (x.shape[0], m, m)).copy()
        return VBState(x, np.array(P0, dtype=float), float(m + 1 + p.tau_R), U)

    def predict(self, model: Model, state: VBState, k: int) -> VBState:
        x, P = ekf_predict(model, state.x, state.P, k)  # x⁻ = f(x⁺), P̃⁻ = A P⁺ Aᵀ + Q̃
        return state._replace(x=x, P=P)

    def update(self, model: Model, state: VBState, k: int, z: Array, side: SideInfo):
        p = self.params
        x_pr = state.x
        B, n = x_pr.shape
        m = z.shape[-1]
        P_pr = np.broadcast_to(state.P, (B, n, n))
        H = np.broadcast_to(model.H(x_pr, k), (B, m, n))  # Jacobian at x⁻, fixed in the loop
        ok = np.isfinite(z)
        nu = np.where(ok, z - model.h(x_pr, k), 0.0)  # prior innovation z − h(x⁻)
        u_pr = p.rho * (state.u - m - 1) + m + 1  # u⁻ = ρ (û − m − 1) + m + 1
        U_pr = p.rho * state.U  # U⁻ = ρ Û
        R_exp = U_pr / (u_pr - m - 1)  # the current E[R], for missing channels
        z0 = np.where(ok, z, 0.0)
        prior = _Prior(x_pr, P_pr, p.tau_P * P_pr, H, z0, nu, ok, bool(ok.all()), U_pr, u_pr + 1.0, R_exp)
        it_ = _Iterate(x_pr, P_pr, U_pr, None, None, None, np.zeros(B, dtype=bool))  # x⁽⁰⁾, P⁽⁰⁾
        active = np.ones(B, dtype=bool)  # with tol > 0 a converged run stops iterating
        iters = np.zeros(B)
        fixed_any = np.zeros(B, dtype=bool)
        for _ in range(p.iterations):
            new = _iteration(model, k, z, prior, it_, p)
            fixed_any |= new.fixed & active
            iters += active
            if p.tol == 0:  # every run iterates N times (the paper)
                it_ = new
                continue
            done = _converged(new.x, it_.x, x_pr, p.tol)
            it_ = _keep(active, new, it_)
            active &= ~done
            if not active.any():
                break
        flags = flag_fix(np.zeros(z.shape, dtype=np.int8), fixed_any)
        R_hat = sym(it_.U / (prior.u - m - 1))  # = the R̂ of each run's last iteration
        trP = np.trace(it_.P_hat, axis1=-2, axis2=-1) / np.trace(P_pr, axis1=-2, axis2=-1)
        out = StepOut(
            x=it_.x,
            P=it_.P,
            innov=nu,
            S=it_.S,
            R_used=it_.R,
            R_hat=R_hat,
            flags=flags,
            stats={"vb_iters": iters, "P_scale": trP},
        )
        return VBState(it_.x, it_.P, prior.u, it_.U), out


class _Prior(NamedTuple):
    """What every iteration of an epoch starts from: x⁻, P̃⁻, T⁻ = τ_P P̃⁻, H at x⁻, z and the prior
    innovation z − h(x⁻) (0 where missing), the channels present (all of them?), U⁻, u = u⁻ + 1 and
    E[R] before the epoch (U⁻/(u⁻ − m − 1)).
    """

    x: Array
    P: Array
    T: Array
    H: Array
    z: Array
    nu: Array
    ok: Array
    all_ok: bool
    U: Array
    u: float
    R_exp: Array


class _Iterate(NamedTuple):
    """One iteration's x⁽ⁱᵗ⁺¹⁾, P⁽ⁱᵗ⁺¹⁾, U, the S and (masked) R̂ of its gain, its P̂ and fix flag."""

    x: Array
    P: Array
    U: Array
    S: Array | None
    R: Array | None
    P_hat: Array | None
    fixed: Array


def _iteration(model: Model, k: int, z: Array, pr: _Prior, it: _Iterate, p: VBEKFParams) -> _Iterate:
    """One fixed-point iteration of every run (the module docstring's loop body)."""
    m = z.shape[-1]
    if p.adapt_P:  # T = T⁻ + P⁽ⁱᵗ⁾ + (x⁽ⁱᵗ⁾ − x⁻)(·)ᵀ ;  P̂ = T/(t − n − 1) = T/(τ_P + 1)
        dx = it.x - pr.x
        P_hat = (pr.T + it.P + dx[:, :, None] * dx[:, None, :]) / (p.tau_P + 1.0)
    else:
        P_hat = pr.P
    r = pr.z - model.h(it.x, k)  # r = z − h(x⁽ⁱᵗ⁾)
    if not pr.all_ok:
        r = np.where(pr.ok, r, 0.0)  # (0 where missing)
    B_R = r[:, :, None] * r[:, None, :] + pr.H @ it.P @ mT(pr.H)  # B_R = r rᵀ + H P⁽ⁱᵗ⁾ Hᵀ
    if pr.all_ok:
        U = pr.U + B_R  # U = U⁻ + B_R
        R_hat = sym(U / (pr.u - m - 1))  # R̂ = U/(u − m − 1)
        nu, H, R = pr.nu, pr.H, R_hat
    else:  # the missing noise's statistic: its expectation given the observed channels
        U = pr.U + _fill_missing(B_R, pr.R_exp, pr.ok)
        R_hat = sym(U / (pr.u - m - 1))
        mk = mask_missing(z, pr.nu, R_hat, H=pr.H)
        nu, H, R = mk.nu, mk.H, mk.R
    PHt = P_hat @ mT(H)
    S = sym(H @ PHt + R)  # H P̂ Hᵀ + R̂
    Kt, fixed = solve_sym(S, mT(PHt))
    K = mT(Kt)  # K = P̂ Hᵀ (H P̂ Hᵀ + R̂)⁻¹
    x = pr.x + mv(K, nu)  # x⁽ⁱᵗ⁺¹⁾ = x⁻ + K (z − h(x⁻))
    P = joseph_from_gain(P_hat, K, PHt, S)  # Joseph; = P̂ − K H P̂ for this gain
    return _Iterate(x, P, U, S, R, P_hat, np.broadcast_to(fixed, (z.shape[0],)))


def _keep(active: Array, new: _Iterate, old: _Iterate) -> _Iterate:
    """``new`` for the active runs, ``old`` for the runs that stopped iterating."""
    if active.all():
        return new
    pick = lambda a, b: np.where(active.reshape((-1,) + (1,) * (a.ndim - 1)), a, b)  # noqa: E731
    return _Iterate(*(pick(a, b) for a, b in zip(new, old, strict=True)))


def _converged(x_new: Array, x_old: Array, x_pr: Array, tol: float) -> Array:
    """(B,) True where ‖x⁽ⁱᵗ⁺¹⁾ − x⁽ⁱᵗ⁾‖ ≤ tol · ‖x⁽ⁱᵗ⁺¹⁾ − x⁻‖ (the fixed point is reached)."""
    step = np.linalg.norm(x_new - x_old, axis=1)
    size = np.linalg.norm(x_new - x_pr, axis=1)
    return step <= tol * size


def _fill_missing(B_R: Array, R_exp: Array, ok: Array) -> Array:
    """E[v vᵀ] for the R-statistic when some channels are missing (ok False), batched.

    The observed block is B_oo = r rᵀ + H P Hᵀ. The missing noise is replaced by its conditional
    expectation under the current E[R] (Gaussian v_m | v_o, A = R_mo R_oo⁻¹)::

        E[v_m v_oᵀ] = A B_oo ,  E[v_m v_mᵀ] = A B_oo Aᵀ + R_mm − A R_om

    i.e. [I; A] B_oo [I; A]ᵀ + [0, 0; 0, Schur] — positive semidefinite. Copying R_exp entries
    into the missing rows and columns instead (the former rule) mixes blocks of two different
    matrices and can make U, hence R̂ and S, indefinite: on smartloc-berlin, where satellites come
    and go, S then went nearly singular and one update threw the state 500 m. A missing channel
    uncorrelated with the observed ones (A = 0) still gets exactly R_mm (its R̂ stays put).
    """
    m = ok.shape[-1]
    okk = ok[:, :, None] & ok[:, None, :]
    miss = ~ok
    eye = np.eye(m)
    M = np.where(okk, R_exp, eye)  # blockdiag(R_oo, I_mm) in the channel order
    C = np.where(miss[:, :, None] & ok[:, None, :], R_exp, 0.0)  # R_mo in the missing rows
    A = mT(np.linalg.solve(M, mT(C)))  # C M⁻¹ (M symmetric): R_mo R_oo⁻¹, zero elsewhere
    T = A + eye * ok[:, None, :]  # rows of observed channels: identity, missing rows: A
    B_oo = np.where(okk, B_R, 0.0)
    schur = np.where(miss[:, :, None] & miss[:, None, :], R_exp - A @ R_exp, 0.0)
    return sym(T @ B_oo @ mT(T) + schur)
