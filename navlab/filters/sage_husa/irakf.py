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

import numpy as np

from navlab.filters.base import REJECTED, REJECTED_AUX, KFLimit, Model, Teaching, band_param, register
from navlab.filters.kalman import Noise, measurement_prediction
from navlab.filters.sage_husa.kernels import RAE, Detection, RAEState, equivalent_variance, irakf_weights
from navlab.linalg import Array, Masked, diag, joseph_from_gain, kf_gain, mv, predict_cov, sym, zero_columns
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
    r_min: float = band_param("r_min")
    r_max: float = band_param("r_max")


@register
class IRAKF(RAE):
    """Improved robust adaptive KF (Ge, Zhang, Tang 2020; ALGORITHMS.md §4.6).

    Per epoch: (1) a parallel, ungated standard KF with the fixed R0 flags channels whose
    innovation exceeds C σ; (2) R̂ from the window of posterior residuals (eq. 3), with P⁻ in
    place of P⁺_{k−1} on flagged epochs (eq. 4); (3) per channel, ν̃ = ν/√S_ii: keep (≤ k0),
    Huber-shrink (≤ k1), or zero the gain column (> k1 or flagged by the SKF); (4) Joseph update,
    so P does not shrink on a rejected channel; (5) the raw posterior residual enters the window.
    """

    key = "irakf"
    label = "IRAKF"
    paper = "Ge, Zhang, Tang 2020 (doi:10.19306/j.cnki.2095-8110.2020.01.007)"
    spec_section = "§4.2–4.6"
    summary = (
        "Windowed residual-based R̂, three-segment IGG/Huber weights that zero the gain of "
        "rejected channels, and a parallel standard KF as a second outlier detector."
    )
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

    def init(self, model: Model, x0: Array, P0: Array) -> RAEState:
        st = super().init(model, x0, P0)
        return st._replace(skf=(st.x.copy(), np.array(P0, dtype=float)))  # the SKF's P: shared if P0 is

    def predict(self, model: Model, state: RAEState, k: int) -> RAEState:
        st = super().predict(model, state, k)  # 2  x⁻ = F x⁺ ;  P⁻ = F P⁺ Fᵀ + Q
        if not self.params.dual_detection:
            return st
        xs, Ps = state.skf  # the parallel SKF's own prediction
        return st._replace(skf=(model.f(xs, k), predict_cov(model.F(k), Ps, model.Q(k))))

    def detect(self, model: Model, state: RAEState, k: int, z: Array) -> Detection:
        """1  Parallel SKF (§4.5): detection flags from its own innovation, then its own update;
        3  the runs whose R̂ takes P⁻ (eq. 4, "improved RAE"): those it flags (or always / never).
        """
        p, (xs, Ps) = self.params, state.skf
        flag, nt = np.zeros(z.shape, dtype=bool), np.zeros(z.shape)
        if p.dual_detection:
            mk = measurement_prediction(model, xs, Ps, k, z, model.R0)
            Ss = sym(mk.M + mk.R)  # S_S = H P_S⁻ Hᵀ + R0
            nt = mk.nu / np.sqrt(diag(Ss))
            flag = (np.abs(nt) > p.C) & mk.ok  # flag_S,i = |ν_S,i| > C √(S_S,ii)
            K, _ = kf_gain(mk.U, Ss)  # the standard KF update; gated option: detections' columns zeroed
            if p.skf_gated and flag.any():
                K = zero_columns(K, flag)
            xs, Ps = xs + mv(K, mk.nu), joseph_from_gain(Ps, K, mk.U, Ss)
        rae = p.improved_rae
        use_prior = flag.any(axis=1) if rae == "conditional" else np.full(z.shape[0], rae == "always")
        return Detection(flag, use_prior, nt, (xs, Ps))

    def weigh(self, mk: Masked, R: Array, S: Array, nt: Array, sig: Array, det: Detection) -> Noise:
        """4–5  Three-segment weights (eq. 7) + the SKF's detections; K from the unmodified R̂."""
        p = self.params
        w, zone = irakf_weights(nt, p.k0, p.k1, p.middle_segment, sig)
        own_reject = (zone == 2) & mk.ok
        aux = det.flag & ~own_reject
        reject = own_reject | aux  # 5  K[:, i] = 0 (weight 0: the KF's gain step zeroes it)
        down = (zone == 1) & ~reject & mk.ok
        R_used, nu = R, np.where(down, w * mk.nu, mk.nu)  # ν_i ← ν_i k0/|ν̃_i|
        if p.middle_zone == "variance" and down.any():
            # option (not S1): the Huber weight as an equivalent variance, so that K and P agree
            # with the down-weighting (S1 shrinks ν only: P then shrinks as if ν were unweighted,
            # which locks out when P⁻ ≫ R̂, e.g. the first epochs of an INS)
            R_used, nu = equivalent_variance(R, w, down), mk.nu
        flags = np.where(own_reject, REJECTED, np.where(aux, REJECTED_AUX, down)).astype(np.int8)
        weights = np.where(reject, 0.0, np.where(down, w, 1.0))
        stats = {"nu_tilde": nt, "skf_nu_tilde": det.nu_tilde, "skf_flag": det.flag.astype(float)}
        stats["improved_rae"] = det.use_prior.astype(float)
        return Noise(R_used, weights=weights, flags=flags, nu=nu, S=S, stats=stats, state={"skf": det.skf})
