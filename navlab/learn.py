"""Teaching material for the Learn page: each filter's idea and equations, and a step-through.

Nothing here imports streamlit. :data:`EQUATIONS` holds the key equations (LaTeX, one string per
``st.latex`` call) per filter key, written from ../shared/ALGORITHMS.md; :data:`IDEAS` a paragraph
per filter. :func:`step_through` runs a registered filter's real ``init`` / ``predict`` /
``update`` with B = 1 on a tiny constant-velocity example (:class:`TinySpec`), with an outlier the
user places, and returns a tidy per-step table: innovation, S, NIS against the χ² threshold,
weights, flags, stats, R_used and R̂ per epoch and channel. A filter that cannot run on the tiny
linear example (it needs an INS, a trained network, side data …) is reported as not applicable
with the reason, never as an exception.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from scipy.stats import chi2

from navlab.errors import NavlabError
from navlab.filters.base import (
    FLAG_NAMES,
    Filter,
    LinearModel,
    SideInfo,
    get_filter_class,
    registry,
)
from navlab.linalg import Array, quad

# ------------------------------------------------------------------------------------ equations
# One list of LaTeX lines per filter key (ALGORITHMS.md section in the comment). Each string is
# shown by one st.latex call; keep them short enough to fit a page.
EQUATIONS: dict[str, list[str]] = {
    # §1.1
    "kf": [
        r"x^-_k = F\,x^+_{k-1}, \qquad P^-_k = F\,P^+_{k-1}F^\top + Q",
        r"\nu_k = z_k - H x^-_k, \qquad S_k = H P^-_k H^\top + R_0",
        r"K_k = P^-_k H^\top S_k^{-1}",
        r"x^+_k = x^-_k + K_k \nu_k, \qquad "
        r"P^+_k = (I - K_kH)P^-_k(I - K_kH)^\top + K_k R_0 K_k^\top",
        r"\gamma_k = \nu_k^\top S_k^{-1}\nu_k \sim \chi^2(m)\ \text{(NIS, if the model is right)}",
    ],
    # §1.4
    "oracle-kf": [
        r"P^-_k = F P^+_{k-1} F^\top + Q + Q^{\mathrm{extra}}_k",
        r"z'_k = z_k - b^{\mathrm{true}}_k, \qquad R_{\mathrm{used}} = R^{\mathrm{true}}_k",
        r"K_k = P^-_k H^\top (H P^-_k H^\top + R^{\mathrm{true}}_k)^{-1}, \qquad "
        r"x^+_k = x^-_k + K_k (z'_k - H x^-_k)",
    ],
    # §1.5
    "chi2-kf": [
        r"\nu_k = z_k - H x^-_k, \qquad S_k = H P^-_k H^\top + R_0",
        r"\gamma_k = \nu_k^\top S_k^{-1} \nu_k",
        r"\gamma_k > \chi^2_{1-\alpha}(m) \;\Rightarrow\; x^+_k = x^-_k,\; P^+_k = P^-_k"
        r"\quad\text{(epoch rejected)}",
        r"\text{otherwise the KF update; per channel: reject } i \text{ if } "
        r"|\nu_i|/\sqrt{S_{ii}} > c_{\mathrm{gate}}",
    ],
    # §1.6
    "student-t-kf": [
        r"\bar\lambda^{(0)} = 1, \qquad R_{\mathrm{eff}} = R_0 / \bar\lambda",
        r"x^+, P^+ = \mathrm{KF}(x^-, P^-, R_{\mathrm{eff}})",
        r"D = (z - Hx^+)(z - Hx^+)^\top + H P^+ H^\top",
        r"\bar\lambda = \dfrac{\nu_t + m}{\nu_t + \operatorname{tr}(D R_0^{-1})}"
        r"\qquad(\text{repeat } N_t \text{ times; } \bar\lambda \ll 1 \text{ marks an outlier})",
    ],
    # §2
    "huber-kf": [
        r"R_0 = L L^\top, \qquad e = L^{-1}(z - H x^-)",
        r"w(e_j) = \begin{cases} 1 & |e_j| < \gamma_H \\ \gamma_H/|e_j| & \text{otherwise}"
        r"\end{cases}, \qquad \gamma_H = 1.345",
        r"\tilde R = L\,\Psi^{-1} L^\top, \qquad \Psi = \operatorname{diag}(w(e_j))",
        r"K = P^- H^\top (H P^- H^\top + \tilde R)^{-1}, \qquad x^+ = x^- + K\nu, \qquad "
        r"P^+ = \mathrm{Joseph}(P^-, K, H, \tilde R)",
    ],
    # §3.1
    "vb-akf": [
        r"\alpha^-_i = \rho\,\alpha_i, \quad \beta^-_i = \rho\,\beta_i, \qquad "
        r"\alpha_i \leftarrow \alpha^-_i + \tfrac12",
        r"\hat R^{(it)} = \operatorname{diag}\!\left(\beta^{(it)}_i / \alpha_i\right)",
        r"K = P^- H^\top (H P^- H^\top + \hat R^{(it)})^{-1}, \quad "
        r"x^{(it+1)} = x^- + K(z - Hx^-), \quad P^{(it+1)} = (I - KH)P^-",
        r"\beta^{(it+1)}_i = \beta^-_i + \tfrac12 (z - H x^{(it+1)})_i^2 "
        r"+ \tfrac12 (H P^{(it+1)} H^\top)_{ii}",
    ],
    # §3.2
    "hakf": [
        r"\alpha^-_i = \rho\,\alpha_i, \quad \beta^-_i = \rho\,\beta_i, \qquad "
        r"\alpha_i \leftarrow \alpha^-_i + \tfrac12",
        r"\hat R^{(it)} = \operatorname{diag}(\beta^{(it)}_i/\alpha_i), \qquad "
        r"e^{(it)} = (\hat R^{(it)})^{-1/2}(z - H x^-)",
        r"\tilde R^{(it)}_{jj} = \hat R^{(it)}_{jj} / w(e^{(it)}_j)\qquad\text{(Huber weight)}",
        r"K^{(it)} = P^- H^\top (H P^- H^\top + \tilde R^{(it)})^{-1}, \quad "
        r"x^{(it+1)} = x^- + K^{(it)}(z - Hx^-)",
        r"\beta^{(it+1)}_i = \beta^-_i + \tfrac12 (z - H x^{(it+1)})_i^2 "
        r"+ \tfrac12 (H P^{(it+1)} H^\top)_{ii}",
    ],
    # §4.1
    "sage-husa": [
        r"d_k = \dfrac{1 - b}{1 - b^{k+1}}, \qquad b = 0.98",
        r"\nu_k = z_k - H x^-_k",
        r"\hat R_k = (1 - d_k)\hat R_{k-1} + d_k\left(\nu_k\nu_k^\top - H P^-_k H^\top\right)"
        r"\quad(\text{eigenvalues clamped})",
        r"K_k = P^-_k H^\top (H P^-_k H^\top + \hat R_k)^{-1}, \qquad x^+_k = x^-_k + K_k\nu_k",
    ],
    # §4.6
    "irakf": [
        r"\text{parallel KF: } \mathrm{flag}_{S,i} = |\nu_{S,i}| > C\sqrt{(S_S)_{ii}}",
        r"\hat R_k = \frac1M \sum_{j=k-M}^{k-1} \eta_j\eta_j^\top + H P_{\mathrm{ref}} H^\top, "
        r"\quad P_{\mathrm{ref}} = \begin{cases} P^-_k & \text{any flag}_S \\ P^+_{k-1} & "
        r"\text{otherwise}\end{cases}",
        r"\tilde\nu_i = \nu_i/\sqrt{S_{ii}}: \quad |\tilde\nu_i| \le k_0: \nu_i;\quad "
        r"k_0 < |\tilde\nu_i| \le k_1: \nu_i k_0/|\tilde\nu_i|;\quad "
        r"|\tilde\nu_i| > k_1 \text{ or flag}_{S,i}: K_{:,i} = 0",
        r"x^+ = x^- + K\nu, \quad P^+ = \mathrm{Joseph}(P^-, K, H, \hat R_k), \quad "
        r"\eta_k = z_k - H x^+_k",
    ],
    # §4.7
    "rrae": [
        r"\hat R_k = \frac1M \sum_{j=k-M}^{k-1}\eta_j\eta_j^\top + H P^+_{k-1} H^\top",
        r"w_i = \begin{cases} 1 & |\tilde\nu_i| \le k_0 \\ \dfrac{k_0}{|\tilde\nu_i|}"
        r"\left(\dfrac{k_1 - |\tilde\nu_i|}{k_1 - k_0}\right)^2 & k_0 < |\tilde\nu_i| \le k_1 \\"
        r" 0 & |\tilde\nu_i| > k_1 \end{cases}",
        r"\bar R_{ii} = \hat R_{k,ii}/w_i \ (0<w_i<1), \qquad \nu_i \leftarrow 0\ (w_i = 0)",
        r"K = P^- H^\top (H P^- H^\top + \bar R)^{-1}, \quad x^+ = x^- + K\nu, \quad "
        r"P^+ = (I - KH)P^-",
    ],
    # §4.8
    "rakf": [
        r"\hat R_k = (1 - d_k)\hat R_{k-1} + d_k(\nu\nu^\top - HP^-H^\top)",
        r"\nu^\top\nu > \gamma_s \operatorname{tr}(HP^-H^\top + \hat R_k) \Rightarrow "
        r"P^- \leftarrow \lambda_k P^-,\ \lambda_k = \max\!\left(1, "
        r"\dfrac{\nu^\top\nu - \operatorname{tr}\hat R_k}{\operatorname{tr}(HP^-H^\top)}\right)",
        r"S = L_S L_S^\top, \quad \nu' = L_S\,\psi_c(L_S^{-1}\nu), \quad "
        r"\psi_c(e) = \operatorname{clip}(e, -c, c)",
        r"K = P^- H^\top S^{-1}, \qquad x^+ = x^- + K\nu'",
    ],
    # §4.9
    "rsshakf": [
        r"S_p = H P^- H^\top + \hat R_{k-1}, \qquad \tilde\nu_i = \nu_i/\sqrt{S_{p,ii}}",
        r"R_{\mathrm{used},ii} = \hat R_{k-1,ii}\,|\tilde\nu_i|/c_r \quad "
        r"\text{if } |\tilde\nu_i| > c_r = 2.5",
        r"x^+, P^+ = \mathrm{KF}(x^-, P^-, R_{\mathrm{used}})",
        r"\hat R_{k,ii} = (1 - d_k)\hat R_{k-1,ii} + d_k\left(\nu_i^2 - (HP^-H^\top)_{ii}\right)",
    ],
    # §1.2
    "ekf": [
        r"x^-_k = f(x^+_{k-1}, u_{k-1}), \qquad A = \partial f/\partial x|_{x^+_{k-1}}, \qquad "
        r"P^-_k = A P^+_{k-1} A^\top + Q",
        r"H = \partial h/\partial x|_{x^-_k}, \qquad \nu_k = z_k - h(x^-_k), \qquad "
        r"S_k = H P^-_k H^\top + R",
        r"K_k = P^-_k H^\top S_k^{-1}, \qquad x^+_k = x^-_k + K_k\nu_k",
    ],
    # §1.3
    "svd-ukf": [
        r"P = U\Sigma_s T^\top, \quad L = U\Sigma_s^{1/2}, \quad "
        r"\chi_0 = \bar x,\ \chi_{j} = \bar x \pm \sqrt{n + \lambda}\,L_j",
        r"x^- = \sum_i W^m_i f(\chi_i), \quad "
        r"P^- = \sum_i W^c_i (\chi^*_i - x^-)(\chi^*_i - x^-)^\top + Q",
        r"Y_i = h(\chi_i),\ \hat z^- = \sum_i W^m_i Y_i,\ "
        r"A = \sum_i W^c_i (Y_i - \hat z^-)(Y_i - \hat z^-)^\top,\ P_{yy} = A + R",
        r"K = P_{xy} P_{yy}^{-1}, \quad x^+ = x^- + K(z - \hat z^-), \quad "
        r"P^+ = P^- - K P_{yy} K^\top",
    ],
    # §5
    "mfukf": [
        r"V = z - \hat z^-, \qquad \gamma = V^\top P_{yy}^{-1} V",
        r"\gamma \le \xi\varepsilon = \xi\,\chi^2_{1-\alpha}(m)\ \Rightarrow\ "
        r"\text{ordinary SVD-UKF update}",
        r"\sigma_i = \min\!\left(\sigma_{\max}, \max\!\left(1, "
        r"\dfrac{V_i^2 - R_{ii}}{A_{ii}}\right)\right)\qquad\text{(fading factors)}",
        r"P^{-\prime} = D_x P^- D_x,\ A' = D_z A D_z,\ P'_{yy} = A' + R,\ "
        r"P'_{xy} = D_x P_{xy} D_z,\ D = \operatorname{diag}(\sqrt{\sigma})",
    ],
    # §6
    "nnmfukf": [
        r"\Psi_j(u) = \exp\!\left(-\dfrac{\|u - C_j\|^2}{2 s_w^2}\right), \qquad "
        r"\hat y(u) = \sum_j W_j \Psi_j(u) + b",
        r"\gamma > \xi\varepsilon \Rightarrow \hat p^{GPS}_k = p^{GPS}_{k-1} + \hat d_k[0{:}3], "
        r"\quad z'_k = p^{INS}_k - \hat p^{GPS}_k \ (\text{and velocity})",
        r"R'_{ii} = \max(R_{ii}, \sigma^2_{NN,i}), \qquad "
        r"\sigma_i = \max\!\left(1, \dfrac{V_i'^2 - R'_{ii}}{A_{ii}}\right)",
    ],
    # §7
    "vb-ekf": [
        r"t^- = n + \tau_P + 1,\ T^- = \tau_P \tilde P^-; \qquad "
        r"u^- = \rho(\hat u_{k-1} - m - 1) + m + 1,\ U^- = \rho\,\hat U_{k-1}",
        r"T = T^- + P^{(it)} + (x^{(it)} - x^-)(x^{(it)} - x^-)^\top, \qquad t = t^- + 1",
        r"U = U^- + r r^\top + H P^{(it)} H^\top,\ r = z - h(x^{(it)}), \qquad u = u^- + 1",
        r"\hat P = T/(t - n - 1), \qquad \hat R = U/(u - m - 1)",
        r"K = \hat P H^\top(H\hat P H^\top + \hat R)^{-1}, \quad "
        r"x^{(it+1)} = x^- + K(z - h(x^-)), \quad P^{(it+1)} = \hat P - K H \hat P",
    ],
    # navlab/filters/wls.py (not in the papers): per-epoch Gauss–Newton, vague prior
    "wls": [
        r"\nu = z_k - h(x), \qquad \Lambda = I/\sigma^2_{\mathrm{prior}}",
        r"x \leftarrow x + (H^\top R_0^{-1} H + \Lambda)^{-1}\left(H^\top R_0^{-1}\nu "
        r"+ \Lambda (x_{\mathrm{prev}} - x)\right)\quad(\text{iterated})",
        r"P_k = (H^\top R_0^{-1} H + \Lambda)^{-1}\qquad"
        r"\text{(no dynamics: each epoch stands alone)}",
    ],
}

IDEAS: dict[str, str] = {
    "kf": (
        "The Kalman filter blends a prediction from the motion model with each new measurement, "
        "weighting them by their covariances: the gain K is large when the prediction is "
        "uncertain (P⁻ large) and small when the measurement is noisy (R large). With linear "
        "models and Gaussian noise of known covariance it is the best possible estimator. The "
        "innovation ν (measurement minus prediction) should look like zero-mean noise with "
        "covariance S; its normalised square, the NIS, follows a χ² law with m degrees of "
        "freedom. A single outlier therefore shows up as a NIS far above the χ² threshold — and "
        "the plain KF swallows it anyway."
    ),
    "oracle-kf": (
        "A KF that cheats: the simulator tells it the noise variance actually used at every epoch "
        "and the mean of every outlier, so it can subtract the outlier and weight the measurement "
        "correctly. No real filter can do better; it is the floor the robust and adaptive filters "
        "are judged against."
    ),
    "chi2-kf": (
        "The simplest robust filter: compute the NIS of the epoch and, if it exceeds the χ² "
        "quantile for the chosen false-alarm rate α, skip the measurement entirely (the state "
        "keeps its prediction). It is all-or-nothing: a gross error is ignored, but so is a "
        "correct measurement that happens to be far from a bad prediction."
    ),
    "student-t-kf": (
        "Models the measurement noise as Student-t (heavy tails) rather than Gaussian. A "
        "variational-Bayes loop alternates between a KF update with an effective noise R₀/λ̄ and a "
        "new estimate of the scale λ̄ from the posterior residual; an outlier makes λ̄ small, which "
        "inflates R for that epoch only."
    ),
    "huber-kf": (
        "Huber's M-estimation applied to the measurement update (Zuo et al. 2017, eqs. 7–10): "
        "normalise the innovation by the measurement noise, give each channel a weight 1 while "
        "it is smaller than γ_H = 1.345 and γ_H/|e| beyond, and inflate that channel's R by 1/w. "
        "Small errors are treated as in the KF (quadratic cost), large ones only linearly, so an "
        "outlier is down-weighted rather than rejected."
    ),
    "vb-akf": (
        "The variational-Bayes adaptive KF (Särkkä & Nummenmaa 2009) treats each channel's noise "
        "variance as unknown with an inverse-gamma distribution (α, β). Each epoch forgets a "
        "little of the past (ρ), then iterates: a KF update with R̂ = β/α, then β grows by the "
        "squared posterior residual plus its uncertainty. R̂ follows a slowly changing noise level; "
        "an outlier also pushes R̂ up for a while."
    ),
    "hakf": (
        "Zuo et al.'s proposal: the VB adaptive KF (tracks a slowly varying R) with Huber weights "
        "inside the same iteration loop, so that a sudden outlier is down-weighted by Huber while "
        "a genuine change of the noise level is learnt by VB. Note that β is fed with the raw "
        "residual, so part of every outlier still leaks into R̂ (the paper's algorithm)."
    ),
    "sage-husa": (
        "The Sage–Husa filter estimates R recursively from the innovations with a fading-memory "
        "weight d_k: R̂ moves towards ννᵀ − HP⁻Hᵀ, the measurement noise the innovation implies. "
        "It adapts to a changing noise level but has no outlier protection: one large innovation "
        "inflates R̂ at once. The estimate can lose positive definiteness, so it is clamped."
    ),
    "irakf": (
        "Ge, Zhang and Tang's IRAKF combines three ideas: R is estimated from a window of "
        "posterior residuals (inflated with the prior covariance when an outlier is suspected); "
        "innovations are weighted in three segments (kept, Huber-shrunk, or their gain column "
        "zeroed so P does not shrink); and a parallel plain KF with fixed R acts as a second "
        "detector whose thresholds do not grow when R̂ does."
    ),
    "rrae": (
        "Robust residual-based adaptive estimation (a reconstruction of Ge et al. 2018): R from a "
        "window of posterior residuals, and Yang's IGG-III equivalent weights — full weight for "
        "small innovations, a smoothly shrinking weight (as an inflated variance) in the middle, "
        "and the innovation set to zero beyond k₁ while P still shrinks, the weakness the IRAKF "
        "paper points out."
    ),
    "rakf": (
        "An improved Sage–Husa filter (a reconstruction of Bai, Han, Qi 2012): Sage–Husa R̂, a "
        "divergence test that inflates P⁻ when the innovation is too large, and a Huber clip of "
        "the whitened innovation. Inflating P⁻ on an outlier makes it trust the bad measurement "
        "more, which is why it suffers from outliers."
    ),
    "rsshakf": (
        "A robust simplified Sage–Husa filter (a reconstruction of Narasimhappa et al. 2016): "
        "R-only Sage–Husa adaptation, and channels whose normalised innovation exceeds c_r get "
        "their variance inflated in proportion for that epoch."
    ),
    "ekf": (
        "The extended KF linearises a nonlinear motion or measurement model around the current "
        "estimate (Jacobians A and H) and then applies the KF equations. On a linear model it is "
        "exactly the KF."
    ),
    "svd-ukf": (
        "The unscented KF propagates a small set of sigma points through the nonlinear models "
        "instead of linearising them. Tan et al. build the sigma points from an SVD of P rather "
        "than a Cholesky factor, so they exist even if P loses positive definiteness through "
        "round-off. On a linear model it equals the KF."
    ),
    "mfukf": (
        "The multiple-fading-factor SVD-UKF tests the NIS against a χ² threshold; when the test "
        "fails, each observed channel gets its own fading factor σ_i ≥ 1 that inflates the "
        "predicted covariance so the innovation becomes consistent. It absorbs a state anomaly "
        "well, but it also follows a measurement gross error, which is the failure Tan et al. "
        "fix with a neural network."
    ),
    "nnmfukf": (
        "Tan et al.'s proposal: when the χ² test fails, first replace the GPS observation by the "
        "prediction of an RBF neural network trained on IMU increments during normal epochs, then "
        "let the fading factors absorb what remains. It needs an INS and a trained network, so it "
        "runs only on the GPS/INS scenario."
    ),
    "vb-ekf": (
        "Huang et al.'s VB filter (applied by Hou et al. 2024 to GPS/INS): both the predicted "
        "covariance P⁻ and a full R get inverse-Wishart distributions, refined by a fixed-point "
        "loop; a wrong Q is absorbed by P̂, a changing noise level by R̂. The prior weights τ_P "
        "and τ_R decide which of the two absorbs a sudden change."
    ),
    "wls": (
        "Weighted least squares solves each epoch on its own, weighting the measurements by R⁻¹: "
        "no motion model, no memory. It is the reference a filter must beat and a quick sanity "
        "check on real data."
    ),
}


# What the tiny example cannot show for a filter that otherwise runs on it.
CAVEATS: dict[str, str] = {
    "nnmfukf": (
        "On the tiny example the RBF network is never trained (it needs IMU increments and "
        "hundreds of clean epochs), so a failed χ² test falls back to the fading factors: the "
        "steps are those of the MFUKF."
    ),
    "ekf": "The tiny example is linear, so the EKF's steps are exactly the KF's.",
    "svd-ukf": "The tiny example is linear, so the SVD-UKF's steps equal the KF's (to round-off).",
    "oracle-kf": (
        "The oracle is told the outlier: its innovation is formed after subtracting it, so its "
        "NIS stays small at the outlier epoch."
    ),
    "wls": "WLS has no dynamics: each step is the measurement alone (the prior is vague).",
}


def base_key(key: str) -> str | None:
    """The documented filter a variant key builds on (``nnmfukf-guarded`` → ``nnmfukf``)."""
    if key in EQUATIONS:
        return key
    bases = [b for b in EQUATIONS if key.startswith(b + "-")]
    return max(bases, key=len) if bases else None


def equations(key: str) -> list[str]:
    """The LaTeX lines for filter ``key``, or its base filter's for a variant ([] if none)."""
    b = base_key(key)
    return list(EQUATIONS[b]) if b else []


def caveat(key: str) -> str:
    """What the tiny example cannot show for ``key`` (or for the filter it is a variant of)."""
    b = base_key(key)
    return CAVEATS.get(key) or (CAVEATS.get(b, "") if b else "")


def idea(cls: type[Filter]) -> str:
    """One paragraph about the filter: :data:`IDEAS`, else its summary and docstring (plus the
    base filter's idea for a variant such as ``nnmfukf-guarded``).
    """
    if cls.key in IDEAS:
        return IDEAS[cls.key]
    doc = (cls.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
    parts = [s for s in (cls.summary, doc) if s]
    text = " ".join(parts) if parts else "No description yet."
    b = base_key(cls.key)
    if b and b in IDEAS:
        text += f" It is a variant of `{b}`: {IDEAS[b]}"
    return text


# ------------------------------------------------------------------------------- tiny example
@dataclass(frozen=True)
class TinySpec:
    """The tiny constant-velocity example of the step-through.

    dims : 1 (state [p, v], one position measurement) or 2 (state [x, y, v_x, v_y], x and y
        measured; the measured states come first, so H = [I 0]).
    epochs : number of updates K.
    outlier_epoch : epoch (1 … K) with an outlier added; 0 = none.
    outlier_size : the outlier in units of the measurement σ (can be negative).
    outlier_channel : "first" or "all" channels get the outlier.
    noise_scale : the true measurement σ is noise_scale·√r (1 = the filters' R is right).
    seed : seed of the measurement and process noise.
    dt, q, r : sampling interval (s), acceleration-noise variance (m²/s⁴), nominal R (m²).
    p0_pos, p0_vel : initial variances (m², m²/s²).
    alpha : false-alarm probability of the χ² threshold drawn against the NIS.
    """

    dims: int = 1
    epochs: int = 8
    outlier_epoch: int = 5
    outlier_size: float = 10.0
    outlier_channel: str = "first"
    noise_scale: float = 1.0
    seed: int = 0
    dt: float = 1.0
    q: float = 0.01
    r: float = 1.0
    p0_pos: float = 4.0
    p0_vel: float = 1.0
    alpha: float = 0.01

    def validate(self) -> TinySpec:
        """Return self, or raise NavlabError saying which value to change."""
        if self.dims not in (1, 2):
            raise NavlabError(f"dims must be 1 or 2, got {self.dims!r}")
        if not isinstance(self.epochs, int) or not 1 <= self.epochs <= 200:
            raise NavlabError(f"epochs must be a whole number in [1, 200], got {self.epochs!r}")
        if not isinstance(self.outlier_epoch, int) or not 0 <= self.outlier_epoch <= self.epochs:
            raise NavlabError(
                f"outlier_epoch must be 0 (none) or an epoch in 1 … {self.epochs}, got {self.outlier_epoch!r}"
            )
        if self.outlier_channel not in ("first", "all"):
            raise NavlabError("outlier_channel must be 'first' or 'all'")
        for name in ("outlier_size", "noise_scale", "dt", "q", "r", "p0_pos", "p0_vel", "alpha"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise NavlabError(f"{name} must be a finite number, got {v!r}")
        for name in ("dt", "r", "p0_pos", "p0_vel", "noise_scale"):
            if getattr(self, name) <= 0:
                raise NavlabError(f"{name} must be positive, got {getattr(self, name)!r}")
        if self.q < 0:
            raise NavlabError(f"q must be ≥ 0, got {self.q!r}")
        if not 0 < self.alpha < 0.5:
            raise NavlabError(f"alpha must be in (0, 0.5), got {self.alpha!r}")
        if abs(self.outlier_size) > 1e6:
            raise NavlabError("outlier_size must be within ±1e6 σ")
        return self


@dataclass(frozen=True, eq=False)
class TinyData:
    """The simulated tiny example (B = 1). Arrays indexed by epoch 0 … K (z[0] is NaN)."""

    spec: TinySpec
    model: LinearModel
    x_true: Array  # (K+1, n)
    z: Array  # (K+1, m)
    R_true: Array  # (K+1, m) variance the noise was drawn with
    bias: Array  # (K+1, m) outlier added (known to the oracle)
    outlier: Array  # (K+1, m) bool
    x0: Array  # (n,) initial estimate
    P0: Array  # (n, n)
    state_names: tuple[str, ...]
    channel_names: tuple[str, ...]

    @property
    def K(self) -> int:
        return int(self.z.shape[0] - 1)

    def side(self, k: int) -> SideInfo:
        return SideInfo(R_true=self.R_true[None, k], bias=self.bias[None, k], outlier=self.outlier[None, k])


def tiny_model(spec: TinySpec) -> tuple[LinearModel, tuple[str, ...], tuple[str, ...]]:
    """The constant-velocity model: (model, state names, channel names). Measured states first."""
    d, dt = spec.dims, spec.dt
    F = np.block([[np.eye(d), dt * np.eye(d)], [np.zeros((d, d)), np.eye(d)]])
    G = np.vstack([0.5 * dt**2 * np.eye(d), dt * np.eye(d)])
    Q = spec.q * G @ G.T
    H = np.hstack([np.eye(d), np.zeros((d, d))])
    R0 = spec.r * np.eye(d)
    if d == 1:
        names, chans = ("p", "v"), ("p",)
    else:
        names, chans = ("x", "y", "v_x", "v_y"), ("x", "y")
    return LinearModel(F, Q, H, R0), names, chans


def simulate_tiny(spec: TinySpec) -> TinyData:
    """Truth and measurements of the tiny example (deterministic in ``spec.seed``)."""
    spec.validate()
    model, names, chans = tiny_model(spec)
    d, K = spec.dims, spec.epochs
    n, m = 2 * d, d
    rng = np.random.default_rng([int(spec.seed), 20261123])
    P0 = np.diag([spec.p0_pos] * d + [spec.p0_vel] * d)
    x = np.zeros((K + 1, n))
    x[0, d:] = 1.0  # moving at 1 m/s (each axis)
    x[0] += rng.standard_normal(n) * np.sqrt(np.diag(P0))
    G = np.vstack([0.5 * spec.dt**2 * np.eye(d), spec.dt * np.eye(d)])
    for k in range(1, K + 1):
        x[k] = model.F_ @ x[k - 1] + G @ (rng.standard_normal(d) * math.sqrt(spec.q))
    x0 = np.zeros(n)
    x0[d:] = 1.0  # the filters' initial estimate: the mean the truth was drawn around
    var = np.full((K + 1, m), spec.r * spec.noise_scale**2)
    noise = rng.standard_normal((K + 1, m)) * np.sqrt(var)
    bias = np.zeros((K + 1, m))
    outlier = np.zeros((K + 1, m), dtype=bool)
    j = spec.outlier_epoch
    if j > 0 and spec.outlier_size != 0:
        ch = slice(0, 1) if spec.outlier_channel == "first" else slice(None)
        bias[j, ch] = spec.outlier_size * np.sqrt(var[j, ch])
        outlier[j, ch] = True
    z = x @ model.H_.T + noise + bias
    z[0] = np.nan
    return TinyData(spec, model, x, z, var, bias, outlier, x0, P0, names, chans)


# -------------------------------------------------------------------------------- step-through
@dataclass(eq=False)
class StepThrough:
    """The outcome of :func:`step_through` for one filter.

    applicable : False if the filter cannot run on the tiny example (``reason`` says why).
    steps : tidy table, one row per (epoch, channel) — see :data:`STEP_COLUMNS` (+ ``stat:<name>``
        columns for the filter's scalar and per-channel stats).
    states : tidy table, one row per (epoch, state): truth, prior, posterior and their variances.
    extra_stats : {epoch: {name: array}} stats of other shapes (e.g. per-iteration VB traces).
    threshold : χ²_{1−α}(m) the NIS is compared with.
    """

    key: str
    label: str
    applicable: bool
    reason: str
    data: TinyData | None
    steps: pd.DataFrame
    states: pd.DataFrame
    extra_stats: dict[int, dict[str, Array]]
    threshold: float

    @property
    def epochs(self) -> int:
        return 0 if self.data is None else self.data.K

    def epoch_table(self) -> pd.DataFrame:
        """One row per epoch: NIS (filter's S, nominal S₀), threshold, outlier, flag, weight."""
        if self.steps.empty:
            return pd.DataFrame(columns=["epoch", "nis", "nis_threshold", "nis_exceeds"])
        g = self.steps.groupby("epoch", sort=True)
        out = g.agg(
            nis=("nis", "first"),
            nis_threshold=("nis_threshold", "first"),
            nis_exceeds=("nis_exceeds", "first"),
            nis_nominal=("nis_nominal", "first"),
            nis_nominal_exceeds=("nis_nominal_exceeds", "first"),
            outlier=("outlier", "any"),
            min_weight=("weight", "min"),
            max_flag=("flag", "max"),
        ).reset_index()
        return out


STEP_COLUMNS = [
    "epoch",
    "t",
    "channel",
    "z",
    "z_pred",
    "truth",
    "innov",
    "S",
    "innov_norm",
    "nis",
    "nis_threshold",
    "nis_exceeds",
    "dof",
    "nis_nominal",
    "nis_nominal_exceeds",
    "R_true",
    "R_used",
    "R_hat",
    "weight",
    "flag",
    "flag_name",
    "outlier",
]
STATE_COLUMNS = ["epoch", "state", "truth", "prior", "posterior", "P_prior", "P_post", "error"]


def _mat(a: Any, m: int) -> Array | None:
    """An (m, m) matrix from an (m, m) or (1, m, m) array."""
    if a is None:
        return None
    a = np.asarray(a, dtype=float)
    if a.ndim == 3:
        a = a[0]
    if a.shape != (m, m):
        raise NavlabError(f"expected an {m}×{m} matrix, got shape {a.shape}")
    return a


def _vec(a: Any, m: int, default: float) -> Array:
    """A length-m vector from (1, m) / (m,) / None."""
    if a is None:
        return np.full(m, default)
    a = np.asarray(a, dtype=float)
    if a.ndim == 2:
        a = a[0]
    return np.broadcast_to(a, (m,)).astype(float)


def _not_applicable(cls: type[Filter], reason: str, data: TinyData | None) -> StepThrough:
    return StepThrough(
        cls.key,
        cls.label,
        False,
        reason,
        data,
        pd.DataFrame(columns=STEP_COLUMNS),
        pd.DataFrame(columns=STATE_COLUMNS),
        {},
        float("nan"),
    )


def _precheck(cls: type[Filter]) -> str | None:
    """A reason why ``cls`` cannot run on the tiny linear example, known without running it."""
    needs = getattr(cls, "needs", None) or getattr(cls, "requires", None)
    if needs:
        return f"it needs {needs}, which the tiny constant-velocity example does not provide"
    return None


def step_through(key: str, spec: TinySpec | None = None, params: dict[str, Any] | None = None) -> StepThrough:
    """Run filter ``key`` on the tiny example with B = 1 and record every step.

    Uses the filter's own ``init`` / ``predict`` / ``update``. Any failure of the filter on this
    example (an exception, a numerical warning, a non-finite result) makes it "not applicable"
    with the reason; an unknown key or bad spec/params raise NavlabError.
    """
    spec = (spec or TinySpec()).validate()
    cls = get_filter_class(key)
    flt = cls(params or {})  # bad parameters are the user's to fix: NavlabError propagates
    data = simulate_tiny(spec)
    pre = _precheck(cls)
    if pre:
        return _not_applicable(cls, pre, data)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            rows, srows, extra = _run(flt, data)
    except NavlabError as exc:
        return _not_applicable(cls, f"not applicable to the tiny linear example: {exc}", data)
    except (FloatingPointError, RuntimeWarning) as exc:
        return _not_applicable(
            cls, f"numerical problem on the tiny example ({type(exc).__name__}: {exc})", data
        )
    except Exception as exc:  # any filter failure becomes a readable reason
        return _not_applicable(
            cls,
            f"cannot run on the tiny linear example ({type(exc).__name__}: {exc}); it may need a "
            "scenario-specific model (an INS, a trained network, pseudoranges)",
            data,
        )
    steps = pd.DataFrame(rows)
    states = pd.DataFrame(srows, columns=STATE_COLUMNS)
    if not np.isfinite(states["posterior"].to_numpy(dtype=float)).all():
        return _not_applicable(cls, "diverged on the tiny example (non-finite estimate)", data)
    thr = float(chi2.ppf(1.0 - spec.alpha, data.model.m))
    return StepThrough(cls.key, cls.label, True, "", data, steps, states, extra, thr)


def _run(flt: Filter, data: TinyData):
    model, spec = data.model, data.spec
    n, m = model.n, model.m
    state = flt.init(model, data.x0[None, :], data.P0.copy())
    rows: list[dict[str, Any]] = []
    srows: list[dict[str, Any]] = []
    extra: dict[int, dict[str, Array]] = {}
    xt = data.x_true
    for i in range(n):
        srows.append(
            {
                "epoch": 0,
                "state": data.state_names[i],
                "truth": xt[0, i],
                "prior": np.nan,
                "posterior": data.x0[i],
                "P_prior": np.nan,
                "P_post": data.P0[i, i],
                "error": data.x0[i] - xt[0, i],
            }
        )
    for k in range(1, data.K + 1):
        st = flt.predict(model, state, k)
        x_prior = np.asarray(st.x, dtype=float).reshape(-1, n)[0].copy()
        P_prior = np.asarray(st.P, dtype=float)
        P_prior = (P_prior[0] if P_prior.ndim == 3 else P_prior).copy()
        zk = data.z[None, k]
        state, out = flt.update(model, st, k, zk, data.side(k))
        x_post = np.asarray(out.x, dtype=float).reshape(-1, n)[0]
        P_post = _mat(out.P, n)
        innov = _vec(out.innov, m, np.nan)
        S = _mat(out.S, m)
        R_used = _mat(out.R_used, m)
        R_hat = _mat(out.R_hat, m) if out.R_hat is not None else None
        weights = _vec(out.weights, m, 1.0)
        flags = _vec(out.flags, m, 0.0).astype(int)
        ok = np.isfinite(data.z[k])
        dof = int(ok.sum())
        stats = dict(out.stats or {})
        if "nis" in stats:
            nis = float(np.asarray(stats.pop("nis"), dtype=float).reshape(-1)[0])
        else:
            nis = float(quad(innov[None, :], S)[0])
        thr = float(chi2.ppf(1.0 - spec.alpha, max(dof, 1)))
        # the same innovation judged with the nominal S₀ = H P⁻ Hᵀ + R₀ (a robust filter's own S
        # is already inflated, which hides the outlier from its own NIS)
        Hk = np.asarray(model.H(x_prior[None, :], k), dtype=float)
        S0 = Hk @ P_prior @ Hk.T + model.R0
        nis_nom = float(quad(innov[None, :], S0)[0])
        scal: dict[str, float] = {}
        perch: dict[str, Array] = {}
        for name, v in stats.items():
            a = np.asarray(v, dtype=float)
            if a.ndim >= 1 and a.shape[0] == 1:
                a = a[0]
            if a.ndim == 0:
                scal[f"stat:{name}"] = float(a)
            elif a.shape == (m,):
                perch[f"stat:{name}"] = a
            else:
                extra.setdefault(k, {})[name] = a
        for i in range(m):
            row = {
                "epoch": k,
                "t": k * spec.dt,
                "channel": data.channel_names[i],
                "z": data.z[k, i],
                "z_pred": data.z[k, i] - innov[i],
                "truth": float(model.H_[i] @ xt[k]),
                "innov": innov[i],
                "S": S[i, i],
                "innov_norm": innov[i] / math.sqrt(S[i, i]) if S[i, i] > 0 else np.nan,
                "nis": nis,
                "nis_threshold": thr,
                "nis_exceeds": bool(nis > thr),
                "dof": dof,
                "nis_nominal": nis_nom,
                "nis_nominal_exceeds": bool(nis_nom > thr),
                "R_true": data.R_true[k, i],
                "R_used": R_used[i, i],
                "R_hat": np.nan if R_hat is None else R_hat[i, i],
                "weight": weights[i],
                "flag": int(flags[i]),
                "flag_name": FLAG_NAMES.get(int(flags[i]), str(int(flags[i]))),
                "outlier": bool(data.outlier[k, i]),
            }
            row.update(scal)
            row.update({name: float(v[i]) for name, v in perch.items()})
            rows.append(row)
        for i in range(n):
            srows.append(
                {
                    "epoch": k,
                    "state": data.state_names[i],
                    "truth": xt[k, i],
                    "prior": x_prior[i],
                    "posterior": x_post[i],
                    "P_prior": P_prior[i, i],
                    "P_post": P_post[i, i],
                    "error": x_post[i] - xt[k, i],
                }
            )
    return rows, srows, extra


def applicability(spec: TinySpec | None = None) -> dict[str, StepThrough]:
    """Run the step-through for every registered filter (each with its default parameters)."""
    return {key: step_through(key, spec) for key in sorted(registry())}


def filter_info(cls: type[Filter]) -> dict[str, Any]:
    """What the Learn page shows about a filter class (plain data, no streamlit)."""
    from navlab.params import describe

    return {
        "key": cls.key,
        "label": cls.label or cls.key,
        "family": cls.family,
        "paper": cls.paper or "textbook",
        "spec_section": cls.spec_section,
        "summary": cls.summary,
        "reconstruction": bool(cls.reconstruction),
        "idea": idea(cls),
        "equations": equations(cls.key),
        "equations_of": base_key(cls.key),
        "caveat": caveat(cls.key),
        "params": describe(cls.Params) if dataclasses.is_dataclass(cls.Params) else [],
    }
