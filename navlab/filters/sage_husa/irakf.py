"""IRAKF — improved robust adaptive KF (Ge, Zhang, Tang 2020 = S1; ALGORITHMS.md §4.2–4.6).

Per epoch, in §4.6's numbering::

    1  parallel standard KF (fixed R0, ungated): flag_S,i = |ν_S,i| > C √(S_S,ii), then its update
    2  x⁻ = F x⁺ ;  P⁻ = F P⁺ Fᵀ + Q
    3  R̂_k = R0 until the window is full, else (1/M) Σ η_j η_jᵀ + H P_ref Hᵀ          (S1 eqs. 3/4)
       with P_ref = P⁻ if any flag_S (eq. 4, "improved RAE"), P⁺_{k−1} otherwise (eq. 3)
    4  S = H P⁻ Hᵀ + R̂_k ;  K = P⁻ Hᵀ S⁻¹ ;  ν = z − H x⁻ ;  ν̃_i = ν_i / √S_ii
    5  per channel: flag_S,i or |ν̃_i| > k1: K[:, i] = 0 (flags 3 / 2);
                    k0 < |ν̃_i| ≤ k1: ν_i ← ν_i k0/|ν̃_i| (flag 1)                      (S1 eq. 7)
    6  x⁺ = x⁻ + K ν ;  P⁺ = Joseph(P⁻, K, H, R̂_k)
    7  η_k = z − H x⁺ into the window (raw, rejected channels included)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from navlab.filters.base import (
    DOWNWEIGHTED,
    REJECTED,
    REJECTED_AUX,
    Filter,
    KFLimit,
    Model,
    SideInfo,
    StepOut,
    Teaching,
    flag_fix,
    register,
)
from navlab.filters.kalman import measurement_prediction
from navlab.filters.sage_husa.kernels import (
    Window,
    check_k0_k1,
    clamp_eig,
    irakf_weights,
    rae_estimate,
    rhat_bounds,
    scale_diag,
    zero_columns,
)
from navlab.linalg import (
    Array,
    PHt,
    batched,
    diag,
    joseph_from_gain,
    kf_gain,
    mask_missing,
    mv,
    predict_cov,
    sym,
)
from navlab.params import param


@dataclass(frozen=True)
class IRAKFParams:
    """IRAKF options (ALGORITHMS.md §4.2–4.6, S1 = Ge, Zhang, Tang 2020)."""

    window: int = param(
        10,
        lo=1,
        hi=5000,
        tune=(3, 100),
        help="RAE window M (epochs of residuals averaged; S1 gives none; R̂ = R0 until full)",
    )
    k0: float = param(
        1.5, lo=0.1, hi=1e6, tune=(0.5, 3.0), help="down-weighting threshold k0 in σ (S1: 0.8–1.5)"
    )
    k1: float = param(3.0, lo=0.1, hi=1e6, tune=(2.0, 10.0), help="rejection threshold k1 in σ (S1: 3.0–5.0)")
    C: float = param(
        3.0,
        lo=0.1,
        hi=1e6,
        tune=(1.5, 10.0),
        help="threshold factor C of the parallel-SKF detector, in σ (Fig. 1)",
    )
    dual_detection: bool = param(True, help="run the parallel standard KF detector (Fig. 1)")
    improved_rae: str = param(
        "conditional",
        choices=("conditional", "always", "never"),
        help="use P⁻ (eq. 4) instead of P⁺ₖ₋₁ (eq. 3) in R̂: on SKF detections / always / never",
    )
    middle_segment: str = param(
        "huber",
        choices=("huber", "literal"),
        help="middle-zone weight: Huber ν·k0/|ν̃| (default) or the seed's literal ν/c1",
    )
    middle_zone: str = param(
        "innovation",
        choices=("innovation", "variance"),
        help="apply the middle-zone weight to ν only, P updated as if unweighted (S1, default), "
        "or as an inflated variance R̂ᵢᵢ/w so P agrees (avoids a lock-out when P0 ≫ R)",
    )
    skf_gated: bool = param(
        False, help="also zero the parallel SKF's gain on its detections (locks out; spec §4.5)"
    )


class IRAKFState(NamedTuple):
    x: Array
    P: Array
    P_post: Array  # P⁺_{k−1}
    win: Window
    xs: Array  # parallel SKF
    Ps: Array


@register
class IRAKF(Filter):
    """Improved robust adaptive KF (Ge, Zhang, Tang 2020; ALGORITHMS.md §4.6).

    Per epoch: (1) a parallel, ungated standard KF with the fixed R0 flags channels whose
    innovation exceeds C σ; (2) R̂ from the window of posterior residuals (eq. 3), with P⁻ in
    place of P⁺_{k−1} on flagged epochs (eq. 4); (3) per channel, ν̃ = ν/√S_ii: keep (≤ k0),
    Huber-shrink (≤ k1), or zero the gain column (> k1 or flagged by the SKF); (4) Joseph update,
    so P does not shrink on a rejected channel; (5) the raw posterior residual enters the window.
    """

    key = "irakf"
    label = "IRAKF"
    family = "robust-adaptive"
    paper = "Ge, Zhang, Tang 2020 (doi:10.19306/j.cnki.2095-8110.2020.01.007)"
    spec_section = "§4.2–4.6"
    summary = (
        "Windowed residual-based R̂, three-segment IGG/Huber weights that zero the gain of "
        "rejected channels, and a parallel standard KF as a second outlier detector."
    )
    estimates_R = True
    Params = IRAKFParams
    kf_limit = KFLimit(
        {"window": 5000, "k0": 1e6, "k1": 1e6, "C": 1e6},
        why="a window longer than the run keeps R̂ = R0; thresholds → ∞ never weight or reject",
    )
    teaching = Teaching(
        idea=(
            "Ge, Zhang and Tang's IRAKF combines three ideas: R is estimated from a window of "
            "posterior residuals (inflated with the prior covariance when an outlier is "
            "suspected); innovations are weighted in three segments (kept, Huber-shrunk, or their "
            "gain column zeroed so P does not shrink); and a parallel plain KF with fixed R acts "
            "as a second detector whose thresholds do not grow when R̂ does."
        ),
        equations=(
            r"\text{parallel KF: } \mathrm{flag}_{S,i} = |\nu_{S,i}| > C\sqrt{(S_S)_{ii}}",
            r"\hat R_k = \frac1M \sum_{j=k-M}^{k-1} \eta_j\eta_j^\top + H P_{\mathrm{ref}} H^\top, "
            r"\quad P_{\mathrm{ref}} = \begin{cases} P^-_k & \text{any flag}_S \\ P^+_{k-1} & "
            r"\text{otherwise}\end{cases}",
            r"\tilde\nu_i = \nu_i/\sqrt{S_{ii}}: \quad |\tilde\nu_i| \le k_0: \nu_i;\quad "
            r"k_0 < |\tilde\nu_i| \le k_1: \nu_i k_0/|\tilde\nu_i|;\quad "
            r"|\tilde\nu_i| > k_1 \text{ or flag}_{S,i}: K_{:,i} = 0",
            r"x^+ = x^- + K\nu, \quad P^+ = \mathrm{Joseph}(P^-, K, H, \hat R_k), \quad "
            r"\eta_k = z_k - H x^+_k",
        ),
    )

    def __init__(self, params: Any = None, **kwargs: Any) -> None:
        super().__init__(params, **kwargs)
        check_k0_k1(self.key, self.params.k0, self.params.k1)

    def init(self, model: Model, x0: Array, P0: Array) -> IRAKFState:
        x0 = np.array(x0, dtype=float)
        B = x0.shape[0]
        P = batched(np.asarray(P0, dtype=float), B).copy()
        win = Window.empty(B, self.params.window, model.m)
        Ps = np.array(P0, dtype=float)  # the ungated SKF keeps a shared P if P0 is shared
        return IRAKFState(x0, P, P, win, x0.copy(), Ps)

    def predict(self, model: Model, state: IRAKFState, k: int) -> IRAKFState:
        F, Q = model.F(k), model.Q(k)
        x = model.f(state.x, k)  # 2  x⁻ = F x⁺
        P = predict_cov(F, state.P, Q)  # 2  P⁻ = F P⁺ Fᵀ + Q
        if self.params.dual_detection:  # the parallel SKF's own prediction
            xs, Ps = model.f(state.xs, k), predict_cov(F, state.Ps, Q)
        else:
            xs, Ps = state.xs, state.Ps
        return state._replace(x=x, P=P, P_post=state.P, xs=xs, Ps=Ps)

    def _skf_step(self, model: Model, state: IRAKFState, k: int, z: Array):
        """1  Parallel SKF (§4.5): detection flags from its own innovation, then its own update."""
        p = self.params
        B, m = z.shape
        if not p.dual_detection:
            return np.zeros((B, m), dtype=bool), np.zeros((B, m)), state.xs, state.Ps
        mk = measurement_prediction(model, state.xs, state.Ps, k, z, model.R0)
        Ss = sym(mk.M + mk.R)  # S_S = H P_S⁻ Hᵀ + R0
        nt_s = mk.nu / np.sqrt(diag(Ss))
        flag_s = (np.abs(nt_s) > p.C) & mk.ok  # flag_S,i = |ν_S,i| > C √(S_S,ii)
        K, _ = kf_gain(mk.U, Ss)  # the standard KF update; gated option: detections' columns zeroed
        if p.skf_gated and flag_s.any():
            K = zero_columns(K, flag_s)
        xs = state.xs + mv(K, mk.nu)
        Ps = joseph_from_gain(state.Ps, K, mk.U, Ss)
        return flag_s, nt_s, xs, Ps

    def update(self, model: Model, state: IRAKFState, k: int, z: Array, side: SideInfo):
        p = self.params
        B, m = z.shape
        flag_s, nt_s, xs, Ps = self._skf_step(model, state, k, z)  # 1
        x_m, P_m = state.x, state.P  # 2 (predict)
        H = model.H(x_m, k)
        U, M = PHt(P_m, H)
        # 3  R̂ by RAE (eq. 3) or improved RAE (eq. 4)
        if p.improved_rae == "conditional":  # eq. 4 on the epochs the parallel SKF flags
            use_prior = flag_s.any(axis=1)
        else:
            use_prior = np.full(B, p.improved_rae == "always")
        flags = np.zeros((B, m), dtype=np.int8)
        if state.win.full:
            HPH_ref = np.where(use_prior[:, None, None], M, PHt(state.P_post, H)[1])  # H P_ref Hᵀ
            lo, hi = rhat_bounds(model.R0)  # eigenvalue guard (only bites with missing channels)
            R_hat, clamped = clamp_eig(rae_estimate(state.win, HPH_ref, model.R0), lo, hi)
            flag_fix(flags, clamped, overwrite=False)
        else:
            R_hat = batched(np.asarray(model.R0, dtype=float), B).copy()
        # 4  gain from the unmodified R̂; normalised innovations
        mk = mask_missing(z, z - model.h(x_m, k), R_hat, U=U, M=M)
        S = sym(mk.M + mk.R)
        K, fixed = kf_gain(mk.U, S)
        sig = np.sqrt(diag(S))
        nt = mk.nu / sig  # ν̃_i = ν_i / √S_ii
        # 5  three-segment weights (eq. 7) + SKF detections: zero gain columns
        w, zone = irakf_weights(nt, p.k0, p.k1, p.middle_segment, sig)
        own_reject = (zone == 2) & mk.ok
        aux_reject = flag_s & ~own_reject
        reject = own_reject | aux_reject
        down = (zone == 1) & ~reject & mk.ok
        R_used, S_used, nu_w = mk.R, S, np.where(down, w * mk.nu, mk.nu)  # ν_i ← ν_i k0/|ν̃_i|
        if p.middle_zone == "variance" and down.any():
            # option (not S1): the Huber weight as an equivalent variance, so that K and P agree
            # with the down-weighting (S1 shrinks ν only: P then shrinks as if ν were unweighted,
            # which locks out when P⁻ ≫ R̂, e.g. the first epochs of an INS)
            R_used = scale_diag(mk.R, np.where(down, 1.0 / np.where(down, w, 1.0), 1.0))
            S_used = sym(mk.M + R_used)
            K, fixed2 = kf_gain(mk.U, S_used)
            fixed = fixed | fixed2
            nu_w = mk.nu
        if reject.any():
            K = zero_columns(K, reject)  # K[:, i] = 0
        # 6  state and Joseph covariance (P keeps the information of rejected channels out)
        x = x_m + mv(K, nu_w)
        P = joseph_from_gain(P_m, K, mk.U, S_used)
        # 7  raw posterior residual into the window (rejected channels included, S1)
        win = state.win.push(z - model.h(x, k), mk.ok)
        flags[down] = DOWNWEIGHTED
        flags[own_reject] = REJECTED
        flags[aux_reject] = REJECTED_AUX
        flag_fix(flags, fixed, overwrite=False)
        out = StepOut(
            x=x,
            P=P,
            innov=mk.nu,
            S=S,
            R_used=R_used,
            R_hat=R_hat,
            weights=np.where(reject, 0.0, np.where(down, w, 1.0)),
            flags=flags,
            stats={
                "nu_tilde": nt,
                "skf_nu_tilde": nt_s,
                "skf_flag": flag_s.astype(float),
                "improved_rae": use_prior.astype(float),
            },
        )
        return IRAKFState(x, P, P, win, xs, Ps), out
