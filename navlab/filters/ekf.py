"""Extended Kalman filter (ALGORITHMS.md §1.2; Hou et al. 2024 eqs. 7–11).

The first-order linearised KF for nonlinear f, h with additive noise (W = V = I)::

    x⁻ = f(x⁺_{k−1}) ;  A = ∂f/∂x at x⁺_{k−1} ;  P⁻ = A P⁺ Aᵀ + Q          (7), (8)
    H = ∂h/∂x at x⁻ ;  ν = z − h(x⁻) ;  S = H P⁻ Hᵀ + R ;  K = P⁻ Hᵀ S⁻¹     (9)
    x⁺ = x⁻ + K ν ;  P⁺ = Joseph(P⁻, K, H, R)                                (10), (11)

For a linear model every step is the KF's (§1.1), so ``ekf`` equals ``kf`` there.

Jacobian of f: the :class:`~navlab.filters.base.Model` protocol's ``F(k)`` does not take the state
(it is the Jacobian for the scenarios whose f is linear, or linearised along a nominal path). A
model whose f is genuinely nonlinear may additionally define ``F_at(x, k) -> (B, n, n)``, the
Jacobian at the posterior mean x⁺_{k−1}; the EKF uses it when present.

References
----------
Hou H., Cheng M., Huang D., Guo S., Wang T., "GPS/INS loose integrated navigation and positioning
algorithm based on VB-EKF", Computer Applications and Software 41(6), 2024,
doi:10.3969/j.issn.1000-386x.2024.06.041.
"""

from __future__ import annotations

from navlab.filters.base import KFLimit, KFState, Model, Teaching, register
from navlab.filters.kalman import KalmanUpdate
from navlab.linalg import Array, mT, sym


def ekf_predict(model: Model, x: Array, P: Array, k: int) -> tuple[Array, Array]:
    """EKF time update k−1 → k: ``x⁻ = f(x⁺)``, ``P⁻ = A P⁺ Aᵀ + Q`` (§1.2 steps 1–2).

    ``A = model.F_at(x⁺, k)`` if the model defines it, else ``model.F(k)``.
    """
    F_at = getattr(model, "F_at", None)
    A = F_at(x, k) if F_at is not None else model.F(k)
    x_prior = model.f(x, k)  # (7) x⁻ = f(x⁺_{k−1}, u_{k−1}, 0)
    P_prior = sym(A @ P @ mT(A) + model.Q(k))  # (8) with W = I
    return x_prior, P_prior


@register
class EKF(KalmanUpdate):
    """Extended Kalman filter with the nominal Q and R, Joseph-form update (ALGORITHMS.md §1.2).

    Its update is the KF's (:class:`~navlab.filters.kalman.KalmanUpdate`): (9) H = ∂h/∂x at x⁻,
    ν = z − h(x⁻), S = H P⁻ Hᵀ + R; (9)–(11) K = P⁻ Hᵀ S⁻¹, x⁺ = x⁻ + K ν, Joseph form.
    """

    key = "ekf"
    label = "EKF"
    family = "nonlinear"
    paper = "Hou et al. 2024 (eqs. 7–11)"
    spec_section = "§1.2"
    summary = (
        "The Kalman filter linearised about the current estimate (Jacobians of f and h); "
        "fixed, assumed-known Q and R. Equals the KF on linear models."
    )
    kf_limit = KFLimit({}, why="the same update as the KF (which linearises h too); F is the model's")
    teaching = Teaching(
        idea=(
            "The extended KF linearises a nonlinear motion or measurement model around the current "
            "estimate (Jacobians A and H) and then applies the KF equations. On a linear model it is "
            "exactly the KF."
        ),
        equations=(
            r"x^-_k = f(x^+_{k-1}, u_{k-1}), \qquad A = \partial f/\partial x|_{x^+_{k-1}}, \qquad "
            r"P^-_k = A P^+_{k-1} A^\top + Q",
            r"H = \partial h/\partial x|_{x^-_k}, \qquad \nu_k = z_k - h(x^-_k), \qquad "
            r"S_k = H P^-_k H^\top + R",
            r"K_k = P^-_k H^\top S_k^{-1}, \qquad x^+_k = x^-_k + K_k\nu_k",
        ),
        caveat="The tiny example is linear, so the EKF's steps are exactly the KF's.",
    )

    def predict(self, model: Model, state: KFState, k: int) -> KFState:
        x, P = ekf_predict(model, state.x, state.P, k)
        return state._replace(x=x, P=P)


__all__ = ["EKF", "ekf_predict"]
