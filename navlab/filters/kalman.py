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

from dataclasses import dataclass, field
from typing import Any, NamedTuple

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
    chi2_threshold,
    diag,
    joseph_from_gain,
    kf_gain,
    mask_missing,
    mv,
    quad,
    sym,
    zero_columns,
)
from navlab.params import param


def measurement_prediction(
    model: Model, x: Array, P: Array, k: int, z: Array, R: Array | None = None, H: Array | None = None
) -> Masked:
    """The innovation and the products the update needs, missing channels dropped (§1.1 step 3).

    ν = z − h(x⁻) with H = ∂h/∂x at x⁻, U = P⁻ Hᵀ, M = H P⁻ Hᵀ; a channel with NaN in z gets a
    zero gain column (:func:`~navlab.linalg.mask_missing`). Returns the masked (ok, ν, R, U, M)
    (R None if not given: a filter that estimates R masks its R̂ once it has it). ``H``: the
    Jacobian at x⁻ if the caller has it already.
    """
    H = model.H(x, k) if H is None else H
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


class Prior(NamedTuple):
    """The prior the update starts from (x⁻, P⁻) at epoch k, its masked innovation products and
    the (unmasked) measurement Jacobian H at x⁻.
    """

    x: Array
    P: Array
    mk: Masked
    k: int
    H: Array


@dataclass
class Noise:
    """What a filter's noise/weight step decides: the R in the gain and what it reports.

    R : the (masked) measurement-noise covariance of the gain, (m, m) or (B, m, m).
    R_hat : the filter's estimate of R (None: it does not estimate one).
    weights : (B, m) per-channel weights; a weight of 0 rejects the channel (its gain column is 0).
    flags : (B, m) per-channel codes of §0.3 (None: all accepted).
    fixed : () or (B,) True where this step needed a numerical repair (flag 9).
    stats : per-run diagnostics for :class:`~navlab.filters.base.StepOut`.
    state : new values of the filter's own state fields (the VB α, β …).
    nu : the innovation the gain multiplies, if not ν (the skew-t's ν′ = ν − Δ E[u]).
    S : the innovation covariance the filter reports (its outlier test's), if not the gain's.
    prior : the prior the gain starts from, if the step changed it (RAKF's inflated P⁻).
    """

    R: Array
    R_hat: Array | None = None
    weights: Array | None = None
    flags: Array | None = None
    fixed: Array | bool = False
    stats: dict[str, Array] = field(default_factory=dict)
    state: dict[str, Array] = field(default_factory=dict)
    nu: Array | None = None
    S: Array | None = None
    prior: Prior | None = None


class KalmanUpdate(Filter):
    """A filter whose measurement update is the KF's, in named steps (§1.1's numbering).

    ``update`` runs ``innovation`` (3: ν, U = P⁻Hᵀ, M = H P⁻ Hᵀ), ``noise`` (the R in the gain:
    the step a robust or adaptive filter overrides, e.g. Huber weights or VB iterations), ``gain``
    (4: K = P⁻ Hᵀ S⁻¹, zero columns for rejected channels) and the posterior (5–6: x⁺ = x⁻ + K ν,
    Joseph-form P⁺). A filter overrides only the steps its paper changes.
    """

    def update(self, model: Model, state: Any, k: int, z: Array, side: SideInfo):
        pr = self.innovation(model, state, k, z, side)  # 3  ν = z − h(x⁻), U = P⁻Hᵀ, M = H P⁻ Hᵀ
        nz = self.noise(model, state, pr, z)  # the R in the gain (and the weights, R̂ …)
        pr = pr if nz.prior is None else nz.prior
        S = sym(pr.mk.M + nz.R)  # 3  S = H P⁻ Hᵀ + R
        K, fixed = self.gain(pr.mk, S, nz)  # 4  K = P⁻ Hᵀ S⁻¹
        x = pr.x + mv(K, pr.mk.nu if nz.nu is None else nz.nu)  # 5  x⁺ = x⁻ + K ν
        P = self.posterior(pr, K, S)  # 6  P⁺
        return self.finish(model, state, k, z, pr, nz, (x, P, S, fixed))

    def finish(
        self, model: Model, state: Any, k: int, z: Array, pr: Prior, nz: Noise, post: tuple
    ) -> tuple[Any, StepOut]:
        """The next state and the step's output from the posterior ``post`` = (x⁺, P⁺, the gain's S,
        its fix flag), the prior and the noise step (what the filter reports beside them).
        """
        x, P, S, fixed = post
        flags = np.zeros(z.shape, dtype=np.int8) if nz.flags is None else nz.flags
        flag_fix(flags, nz.fixed | fixed)
        out = StepOut(
            x=x,
            P=P,
            innov=pr.mk.nu,
            S=S if nz.S is None else nz.S,
            R_used=nz.R,
            R_hat=nz.R_hat,
            weights=nz.weights,
            flags=flags,
            stats=nz.stats,
        )
        return self.next_state(model, state, k, z, x, P, nz), out

    def innovation(self, model: Model, state: Any, k: int, z: Array, side: SideInfo) -> Prior:
        """3  The prior and its innovation products (the nominal R0 masked with them)."""
        H = model.H(state.x, k)
        return Prior(
            state.x, state.P, measurement_prediction(model, state.x, state.P, k, z, model.R0, H), k, H
        )

    def noise(self, model: Model, state: Any, pr: Prior, z: Array) -> Noise:
        """The R in the gain: the nominal R0 (the KF)."""
        return Noise(pr.mk.R)

    def gain(self, mk: Masked, S: Array, nz: Noise) -> tuple[Array, Array]:
        """4  K = P⁻ Hᵀ S⁻¹, with a zero column for every rejected channel (weight 0)."""
        K, fixed = kf_gain(mk.U, S)
        if nz.weights is not None and not np.all(nz.weights):
            K = zero_columns(K, nz.weights == 0)
        return K, fixed

    def posterior(self, pr: Prior, K: Array, S: Array) -> Array:
        """6  P⁺ = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ (Joseph form, from U = P⁻Hᵀ and S)."""
        return joseph_from_gain(pr.P, K, pr.mk.U, S)

    def next_state(self, model: Model, state: Any, k: int, z: Array, x: Array, P: Array, nz: Noise) -> Any:
        """The state after the update: x⁺, P⁺ and the filter's own fields (``nz.state``)."""
        return state._replace(x=x, P=P, **nz.state)


@register
class KF(KalmanUpdate):
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


def true_R(side: SideInfo, m: int) -> Array:
    """The oracle's R, the simulator's true variances: (m, m) while every run's are the same (no
    outlier at this epoch: P then stays shared by the runs, as the KF's), else (B, m, m).

    As the χ²-KF's shared P, this makes a run's last bits depend on the runs beside it where
    outliers make the true R differ (the shared and the batched gain round differently).
    """
    r = side.R_true
    return (r[0] if (r == r[:1]).all() else r)[..., :, None] * np.eye(m)


@dataclass(frozen=True)
class OracleParams:
    """Oracle KF options."""

    mode: str = param(
        "exact",
        choices=("exact", "skip"),
        help="exact: true R(t), known outlier mean removed (MMSE floor); skip: ignore outlier epochs",
    )


@register
class OracleKF(KalmanUpdate):
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

    def innovation(self, model: Model, state: KFState, k: int, z: Array, side: SideInfo) -> Prior:
        P = state.P if side.Q_extra is None else state.P + side.Q_extra  # (§1.4 step 1)
        # (§1.4 step 2) z' = z − b_true, R_used = R_true (or: drop the contaminated channels)
        z = np.where(side.outlier, np.nan, z) if self.params.mode == "skip" else z - side.bias
        R = true_R(side, z.shape[-1])
        H = model.H(state.x, k)
        return Prior(state.x, P, measurement_prediction(model, state.x, P, k, z, R, H), k, H)

    def noise(self, model: Model, state: KFState, pr: Prior, z: Array) -> Noise:
        return Noise(pr.mk.R, R_hat=pr.mk.R)  # the true R, reported as its "estimate"


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
class Chi2KF(KalmanUpdate):
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

    def noise(self, model: Model, state: KFState, pr: Prior, z: Array) -> Noise:
        """The gate: weight 0 (gain column zeroed) for a rejected epoch or channel (flag 2)."""
        p, mk = self.params, pr.mk
        S = sym(mk.M + mk.R)  # S = H P⁻ Hᵀ + R0
        nis = quad(mk.nu, S)  # γ = νᵀ S⁻¹ ν
        if p.per_channel:  # option: reject channel i where |ν̃_i| > c_gate
            reject = (np.abs(mk.nu) > p.c_gate * np.sqrt(diag(S))) & mk.ok
        else:  # 4  γ > χ²_{1−α}(m): x⁺ = x⁻, P⁺ = P⁻ (the epoch rejected), else the KF update
            dof = mk.ok.sum(axis=1)
            epoch = (nis > chi2_threshold(p.alpha, dof, z.shape[-1])) & (dof > 0)
            reject = epoch[:, None] & mk.ok
        weights = (
            np.where(epoch[:, None], 0.0, 1.0) * np.ones(z.shape)
            if not p.per_channel
            else (~reject).astype(float)
        )
        flags = np.where(reject, REJECTED, 0).astype(np.int8)
        return Noise(mk.R, weights=weights, flags=flags, stats={"nis": nis})
