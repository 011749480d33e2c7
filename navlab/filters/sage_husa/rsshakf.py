"""RSSHAKF — robust simplified Sage–Husa KF (RECONSTRUCTION; ALGORITHMS.md §4.9).

S1 ref. [18] (Narasimhappa, Sabat, Nayak 2016) could not be retrieved; navlab's reading, in §4.9's
numbering::

    1  x⁻, P⁻ ;  ν = z − H x⁻ ;  S_p = H P⁻ Hᵀ + R̂_{k−1} ;  ν̃_i = ν_i / √S_p,ii
    2  outlier channels O = { i : |ν̃_i| > c_r },  c_r = 2.5
    3  R_used = R̂_{k−1} with R_used,ii ← R̂_{k−1,ii} |ν̃_i|/c_r for i ∈ O   (variance inflation)
    4  KF update with R_used (Joseph)
    5  R̂_k,ii = (1 − d_k) R̂_{k−1,ii} + d_k (ν_i² − (H P⁻ Hᵀ)_ii) on every channel (diagonal R̂,
       clamped as §4.1; option: skip the channels in O)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from navlab.filters.base import DOWNWEIGHTED, R_HAT_AT_BAND, KFLimit, Model, Teaching, band_param, register
from navlab.filters.kalman import Noise, Prior
from navlab.filters.sage_husa.kernels import FadingMemory, RState, scale_diag
from navlab.linalg import Array, diag, diag_embed, mask_missing
from navlab.params import param


@dataclass(frozen=True)
class RSSHAKFParams:
    """RSSHAKF options (ALGORITHMS.md §4.9, RECONSTRUCTION of Narasimhappa et al. 2016)."""

    b: float = param(0.98, lo=0.5, hi=1.0, tune=(0.8, 0.999), help="Sage–Husa forgetting factor b")
    adapt: bool = param(True, help="estimate the diagonal R̂ (off: R̂ stays diag R0)")
    c_r: float = param(
        2.5,
        lo=0.1,
        hi=1e12,
        tune=(1.0, 10.0),
        help="outlier threshold c_r on |ν̃| (variance inflation above it)",
    )
    exclude_outliers: bool = param(
        False,
        help="skip the Sage–Husa update on outlier channels (variant; inverts S1's ranking, §4.9)",
    )
    r_min: float = band_param("r_min")
    r_max: float = band_param("r_max")


@register
class RSSHAKF(FadingMemory):
    """Robust simplified Sage–Husa KF (RECONSTRUCTION, ALGORITHMS.md §4.9).

    R-only, diagonal Sage–Husa; channels with |ν̃_i| > c_r (ν̃ from R̂_{k−1}) get their variance
    inflated by |ν̃_i|/c_r for this update; the Sage–Husa update then runs on every channel.
    """

    key = "rsshakf"
    label = "RSSHAKF (reconstruction)"
    family = "robust-adaptive"
    paper = "Narasimhappa, Sabat, Nayak 2016 (IEEE Sensors J. 16(10)), cited as S1 ref. [18]"
    spec_section = "§4.9"
    summary = (
        "RECONSTRUCTION (paper not retrievable): diagonal Sage–Husa R̂ with variance inflation "
        "of channels whose normalised innovation exceeds c_r."
    )
    reconstruction = True
    Params = RSSHAKFParams
    kf_limit = KFLimit(
        {"adapt": False, "c_r": 1e12},
        why="R̂ fixed at diag R0 and no channel above c_r → ∞ (the KF when R0 is diagonal)",
    )
    teaching = Teaching(
        idea=(
            "A robust simplified Sage–Husa filter (a reconstruction of Narasimhappa et al. 2016): "
            "R-only Sage–Husa adaptation, and channels whose normalised innovation exceeds c_r get "
            "their variance inflated in proportion for that epoch."
        ),
        equations=(
            r"S_p = H P^- H^\top + \hat R_{k-1}, \qquad \tilde\nu_i = \nu_i/\sqrt{S_{p,ii}}",
            r"R_{\mathrm{used},ii} = \hat R_{k-1,ii}\,|\tilde\nu_i|/c_r \quad "
            r"\text{if } |\tilde\nu_i| > c_r = 2.5",
            r"x^+, P^+ = \mathrm{KF}(x^-, P^-, R_{\mathrm{used}})",
            r"\hat R_{k,ii} = (1 - d_k)\hat R_{k-1,ii} + d_k\left(\nu_i^2 - (HP^-H^\top)_{ii}\right)",
        ),
    )

    def init(self, model: Model, x0: Array, P0: Array) -> RState:
        st = super().init(model, x0, P0)
        return st._replace(R=diag_embed(diag(st.R)))  # diagonal R̂ (§4.9)

    def noise(self, model: Model, state: RState, pr: Prior, z: Array) -> Noise:
        p, mk = self.params, pr.mk
        R = mask_missing(z, mk.nu, state.R).R
        nt = mk.nu / np.sqrt(diag(mk.M) + diag(R))  # 1  ν̃ with R̂_{k−1} (diag of H P⁻ Hᵀ + R̂)
        out_ch = (np.abs(nt) > p.c_r) & mk.ok  # 2  outlier channels
        infl = np.where(out_ch, np.abs(nt) / p.c_r, 1.0)  # 3  R_ii · |ν̃_i|/c_r (4: the KF update)
        upd = mk.ok & ~out_ch if p.exclude_outliers else mk.ok  # 5  on every channel (option: not O)
        R_hat, clamped, _ = self.sage_husa(model, state, pr, upd, diagonal=True)  # 5  diagonal R̂_k
        flags = np.where(out_ch, DOWNWEIGHTED, np.where(clamped, R_HAT_AT_BAND, 0)).astype(np.int8)
        return Noise(
            scale_diag(R, infl), R_hat=R_hat, weights=1.0 / infl, flags=flags, stats={"nu_tilde": nt}
        )
