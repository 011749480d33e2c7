"""Baseline Kalman filters: the standard KF, the oracle KF and the χ²-gated KF.

These also work on nonlinear models (they then are the EKF update: h(x⁻) and its Jacobian).

The measurement update of every KF-family filter in navlab is written with the two functions of
this module, in ALGORITHMS.md §1.1's numbering::

    3  ν = z − h(x⁻) ;  S = H P⁻ Hᵀ + R          measurement_prediction (+ S in kf_update)
    4  K = P⁻ Hᵀ S⁻¹                             kf_update
    5  x⁺ = x⁻ + K ν                             kf_update
    6  P⁺ = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ     kf_update (Joseph form)

in terms of U = P⁻ Hᵀ and M = H P⁻ Hᵀ, which every filter needs anyway (its own tests of the
innovation, its R̂). Speed tricks used here (navlab/linalg.py, worth measured by
``benchmarks/tricks.py``): U and M by indexing for a selection H (:func:`~navlab.linalg.PHt`), the
closed-form S⁻¹ for m ≤ 3 (:func:`~navlab.linalg.kf_gain`), the Joseph form from U and S
(:func:`~navlab.linalg.joseph_from_gain`), and a shared P (the same in every run while the gain
does not depend on the data) kept unbatched. The plain transcriptions are
:mod:`navlab.filters.reference.kalman`.

References
----------
R. E. Kalman, "A new approach to linear filtering and prediction problems", J. Basic Eng. 82, 1960.
Y. Bar-Shalom, X. R. Li, T. Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, Wiley 2001 (ch. 5: consistency; NIS gating).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from navlab.filters.base import (
    REJECTED,
    Filter,
    KFLimit,
    KFState,
    Model,
    SideInfo,
    StepOut,
    Teaching,
    flag_fix,
    register,
)
from navlab.linalg import (
    Array,
    Masked,
    PHt,
    bcast,
    chi2_threshold,
    diag,
    joseph_from_gain,
    kf_gain,
    mask_missing,
    mv,
    quad,
    sym,
)
from navlab.params import param


def measurement_prediction(
    model: Model, x: Array, P: Array, k: int, z: Array, R: Array | None = None
) -> Masked:
    """The innovation and the products the update needs, missing channels dropped (§1.1 step 3).

    ν = z − h(x⁻) with H = ∂h/∂x at x⁻, U = P⁻ Hᵀ, M = H P⁻ Hᵀ; a channel with NaN in z gets a
    zero gain column (:func:`~navlab.linalg.mask_missing`). Returns the masked (ok, ν, R, U, M)
    (R None if not given: a filter that estimates R masks its R̂ once it has it).
    """
    H = model.H(x, k)
    nu = z - model.h(x, k)
    U, M = PHt(P, H)
    return mask_missing(z, nu, R, U=U, M=M)


def kf_update(
    x: Array, P: Array, U: Array, M: Array, nu: Array, R: Array
) -> tuple[Array, Array, Array, Array, Array]:
    """The Kalman measurement update with covariance R (§1.1 steps 3–6), from U = P⁻Hᵀ, M = H P⁻ Hᵀ.

    Returns
    -------
    x, P : posterior mean and (Joseph-form, symmetrised) covariance.
    S : innovation covariance H P⁻ Hᵀ + R.
    K : the gain P⁻ Hᵀ S⁻¹.
    fixed : () or (B,) True where S needed a numerical fix (flag 9).
    """
    S = sym(M + R)  # 3  S = H P⁻ Hᵀ + R
    K, fixed = kf_gain(U, S)  # 4  K = P⁻ Hᵀ S⁻¹
    x = x + mv(K, nu)  # 5  x⁺ = x⁻ + K ν
    P = joseph_from_gain(P, K, U, S)  # 6  P⁺ = (I − KH) P⁻ (I − KH)ᵀ + K R Kᵀ
    return x, P, S, K, fixed


def _flags(z: Array, fixed: Array) -> Array:
    return flag_fix(np.zeros(z.shape, dtype=np.int8), fixed)


@register
class KF(Filter):
    """Standard Kalman filter with the nominal Q and R, Joseph-form update (ALGORITHMS.md §1.1)."""

    key = "kf"
    label = "KF"
    family = "baseline"
    spec_section = "§1.1"
    summary = "The optimal linear-Gaussian filter with fixed, assumed-known Q and R: the reference."
    kf_limit = KFLimit({}, why="it is the KF")
    teaching = Teaching(
        idea=(
            "The Kalman filter blends a prediction from the motion model with each new measurement, "
            "weighting them by their covariances: the gain K is large when the prediction is "
            "uncertain (P⁻ large) and small when the measurement is noisy (R large). With linear "
            "models and Gaussian noise of known covariance it is the best possible estimator. The "
            "innovation ν (measurement minus prediction) should look like zero-mean noise with "
            "covariance S; its normalised square, the NIS, follows a χ² law with m degrees of "
            "freedom. A single outlier therefore shows up as a NIS far above the χ² threshold — and "
            "the plain KF swallows it anyway."
        ),
        equations=(
            r"x^-_k = F\,x^+_{k-1}, \qquad P^-_k = F\,P^+_{k-1}F^\top + Q",
            r"\nu_k = z_k - H x^-_k, \qquad S_k = H P^-_k H^\top + R_0",
            r"K_k = P^-_k H^\top S_k^{-1}",
            r"x^+_k = x^-_k + K_k \nu_k, \qquad "
            r"P^+_k = (I - K_kH)P^-_k(I - K_kH)^\top + K_k R_0 K_k^\top",
            r"\gamma_k = \nu_k^\top S_k^{-1}\nu_k \sim \chi^2(m)\ \text{(NIS, if the model is right)}",
        ),
    )

    def update(self, model: Model, state: KFState, k: int, z: Array, side: SideInfo):
        mk = measurement_prediction(model, state.x, state.P, k, z, model.R0)  # (3)
        x, P, S, _, fixed = kf_update(state.x, state.P, mk.U, mk.M, mk.nu, mk.R)  # (3)–(6)
        return KFState(x, P), StepOut(x=x, P=P, innov=mk.nu, S=S, R_used=mk.R, flags=_flags(z, fixed))


@dataclass(frozen=True)
class OracleParams:
    """Oracle KF options."""

    mode: str = param(
        "exact",
        choices=("exact", "skip"),
        help="exact: true R(t), known outlier mean removed (MMSE floor); skip: ignore outlier epochs",
    )


@register
class OracleKF(Filter):
    """The KF that knows the true R(t), the outlier epochs and means, and any Q anomaly (§1.4).

    It is the exact MMSE filter of the simulated model: the floor every robust or adaptive filter
    is judged against. ``mode="skip"`` instead drops contaminated channels; it is NOT a floor for
    zero-mean outliers (they still carry information).
    """

    key = "oracle-kf"
    label = "Oracle KF"
    family = "oracle"
    spec_section = "§1.4"
    summary = "Knows the true noise: the accuracy floor (needs simulator ground truth)."
    estimates_R = True  # it reports the true R as its "estimate", so plots show the truth
    Params = OracleParams
    kf_limit = KFLimit({}, why="with the nominal R and no outliers it knows nothing the KF does not")
    teaching = Teaching(
        idea=(
            "A KF that cheats: the simulator tells it the noise variance actually used at every "
            "epoch and the mean of every outlier, so it can subtract the outlier and weight the "
            "measurement correctly. No real filter can do better; it is the floor the robust and "
            "adaptive filters are judged against."
        ),
        equations=(
            r"P^-_k = F P^+_{k-1} F^\top + Q + Q^{\mathrm{extra}}_k",
            r"z'_k = z_k - b^{\mathrm{true}}_k, \qquad R_{\mathrm{used}} = R^{\mathrm{true}}_k",
            r"K_k = P^-_k H^\top (H P^-_k H^\top + R^{\mathrm{true}}_k)^{-1}, \qquad "
            r"x^+_k = x^-_k + K_k (z'_k - H x^-_k)",
        ),
        caveat=(
            "The oracle is told the outlier: its innovation is formed after subtracting it, so its "
            "NIS stays small at the outlier epoch."
        ),
    )

    def update(self, model: Model, state: KFState, k: int, z: Array, side: SideInfo):
        P_prior = state.P if side.Q_extra is None else state.P + side.Q_extra  # (§1.4 step 1)
        # (§1.4 step 2) z' = z − b_true, R_used = R_true (or: drop the contaminated channels)
        z = np.where(side.outlier, np.nan, z) if self.params.mode == "skip" else z - side.bias
        R = side.R_true[..., :, None] * np.eye(z.shape[-1])
        mk = measurement_prediction(model, state.x, P_prior, k, z, R)
        x, P, S, _, fixed = kf_update(state.x, P_prior, mk.U, mk.M, mk.nu, mk.R)  # (§1.4 step 3)
        out = StepOut(x=x, P=P, innov=mk.nu, S=S, R_used=mk.R, R_hat=mk.R, flags=_flags(z, fixed))
        return KFState(x, P), out


@dataclass(frozen=True)
class Chi2Params:
    """χ²-gated KF options (ALGORITHMS.md §1.5)."""

    alpha: float = param(
        0.01, lo=1e-6, hi=0.5, tune=(1e-4, 0.2), help="false-alarm probability of the NIS gate"
    )
    per_channel: bool = param(
        False, help="gate each channel on |ν_i|/√S_ii > c_gate instead of the whole epoch"
    )
    c_gate: float = param(
        3.0, lo=0.5, hi=100.0, tune=(1.5, 10.0), help="per-channel gate in innovation sigmas"
    )


@register
class Chi2KF(Filter):
    """KF that skips measurements whose NIS exceeds the χ² gate (ALGORITHMS.md §1.5)."""

    key = "chi2-kf"
    label = "χ²-gated KF"
    family = "robust"
    spec_section = "§1.5"
    summary = "Rejects an epoch whose normalised innovation squared fails a χ² test."
    Params = Chi2Params
    kf_limit = KFLimit(
        {"alpha": 1e-6, "c_gate": 100.0},
        why="α → 0 (per channel: c_gate → ∞) moves the gate to ∞: no epoch of clean data fails it",
    )
    teaching = Teaching(
        idea=(
            "The simplest robust filter: compute the NIS of the epoch and, if it exceeds the χ² "
            "quantile for the chosen false-alarm rate α, skip the measurement entirely (the state "
            "keeps its prediction). It is all-or-nothing: a gross error is ignored, but so is a "
            "correct measurement that happens to be far from a bad prediction."
        ),
        equations=(
            r"\nu_k = z_k - H x^-_k, \qquad S_k = H P^-_k H^\top + R_0",
            r"\gamma_k = \nu_k^\top S_k^{-1} \nu_k",
            r"\gamma_k > \chi^2_{1-\alpha}(m) \;\Rightarrow\; x^+_k = x^-_k,\; P^+_k = P^-_k"
            r"\quad\text{(epoch rejected)}",
            r"\text{otherwise the KF update; per channel: reject } i \text{ if } "
            r"|\nu_i|/\sqrt{S_{ii}} > c_{\mathrm{gate}}",
        ),
    )

    def update(self, model: Model, state: KFState, k: int, z: Array, side: SideInfo):
        p = self.params
        x0, P0 = state.x, state.P
        B = z.shape[0]
        mk = measurement_prediction(model, x0, P0, k, z, model.R0)  # 1–3
        S = sym(mk.M + mk.R)
        K, fixed = kf_gain(mk.U, S)
        nis = quad(mk.nu, S)  # γ = νᵀ S⁻¹ ν
        flags = np.zeros(z.shape, dtype=np.int8)
        if p.per_channel:  # option: reject channel i where |ν̃_i| > c_gate (zero its gain column)
            reject = (np.abs(mk.nu) > p.c_gate * np.sqrt(diag(S))) & mk.ok
            K = bcast(K, (B, *K.shape[-2:])) * ~reject[:, None, :]
            flags[reject] = REJECTED
            x = x0 + mv(K, mk.nu)
            P = joseph_from_gain(P0, K, mk.U, S)  # Joseph: the gain is no longer optimal
            weights = (~reject).astype(float)
        else:  # 4  γ > χ²_{1−α}(m): x⁺ = x⁻, P⁺ = P⁻ (epoch rejected), else the KF update
            dof = mk.ok.sum(axis=1)
            reject = (nis > chi2_threshold(p.alpha, dof, z.shape[-1])) & (dof > 0)
            x1 = x0 + mv(K, mk.nu)
            P1 = joseph_from_gain(P0, K, mk.U, S)
            x = np.where(reject[:, None], x0, x1)
            P = np.where(reject[:, None, None], P0, P1) if reject.any() else P1
            flags[reject[:, None] & mk.ok] = REJECTED
            weights = np.where(reject[:, None], 0.0, 1.0) * np.ones(z.shape)
        flag_fix(flags, fixed)
        out = StepOut(
            x=x, P=P, innov=mk.nu, S=S, R_used=mk.R, weights=weights, flags=flags, stats={"nis": nis}
        )
        return KFState(x, P), out
