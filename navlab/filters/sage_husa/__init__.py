"""Sage–Husa family: classic SHAKF, IRAKF (Ge, Zhang, Tang 2020) and its three comparators.

Every filter here estimates the measurement-noise covariance R from the innovations or the
posterior residuals, and (except the classic SHAKF) protects itself against outliers. One module
per filter, each with its spec section's steps at the top and their numbers at the lines:

* :mod:`.shakf` ``sage-husa`` — classic fading-memory Sage–Husa R estimate (ALGORITHMS.md §4.1);
* :mod:`.irakf` ``irakf`` — windowed residual R estimate (RAE, S1 eq. 3) with the prior covariance
  of eq. 4 on suspect epochs, a three-segment IGG/Huber weight function with gain-column zeroing
  (eq. 7) and dual detection by a parallel standard KF (Fig. 1) (§4.2–4.6);
* :mod:`.rrae` ``rrae`` — RAE + classical IGG-III equivalent weights (§4.7, RECONSTRUCTION);
* :mod:`.rakf` ``rakf`` — Sage–Husa + divergence-triggered P inflation + whitened-innovation Huber
  clipping (§4.8, RECONSTRUCTION);
* :mod:`.rsshakf` ``rsshakf`` — simplified (R-only, diagonal) Sage–Husa + outlier variance
  inflation (§4.9, RECONSTRUCTION);

and what they share in :mod:`.kernels`: the weight functions, the fading weight, the residual
window, the two R̂ steps written for one run (Sage–Husa's and RAE's, behind one eigenvalue
guard), and two templates, each a :class:`navlab.filters.kalman.KalmanUpdate` in named steps:
:class:`~.kernels.FadingMemory` (SHAKF, RAKF, RSSHAKF: the state carries R̂ and the update count
of d_k; its Sage–Husa step) and :class:`~.kernels.RAE` (RRAE, IRAKF: the residual window, a
second detector, the window R̂, then the filter's weights). Each filter overrides only its own
steps: its noise/weight step (the weights of its paper), IRAKF its detector, RRAE the gain and the
short-form posterior; the KF's innovation, gain and Joseph posterior are the rest.

References
----------
A. P. Sage, G. W. Husa, "Adaptive filtering with unknown prior statistics", JACC 1969.
Ge B., Zhang H., Tang Z., "Improved robust adaptive Kalman filter with innovation-based outliers
diagnosis", Navigation Positioning and Timing 7(1), 2020, doi:10.19306/j.cnki.2095-8110.2020.01.007.
A. H. Mohamed, K. P. Schwarz, "Adaptive Kalman filtering for INS/GPS", J. Geodesy 73, 1999.
Yang Y., He H., Xu G., "Adaptively robust filtering for kinematic geodetic positioning",
J. Geodesy 75, 2001 (IGG-III equivalent weights).
Bai Y. Q., Han J. H., Qi X. H., "Data processing algorithm of MEMS inclinometer based on improved
Sage-Husa adaptive Kalman filter", Chinese Control Conference 2012 (abstract only).
M. Narasimhappa, S. L. Sabat, J. Nayak, "Fiber-optic gyroscope signal denoising using an adaptive
robust Kalman filter", IEEE Sensors J. 16(10), 2016 (not retrieved).
"""

# the registration order is the order the app lists the filters in (§4.1 … §4.9)
# isort: off
from navlab.filters.sage_husa.shakf import SageHusa
from navlab.filters.sage_husa.irakf import IRAKF
from navlab.filters.sage_husa.rrae import RRAE
from navlab.filters.sage_husa.rakf import RAKF
from navlab.filters.sage_husa.rsshakf import RSSHAKF
from navlab.filters.sage_husa.kernels import (
    clamp_to_band,
    forgetting_weight,
    igg3_weights,
    irakf_weights,
    rae_rhat,
)

# isort: on

__all__ = ["IRAKF", "RAKF", "RRAE", "RSSHAKF", "SageHusa"]
__all__ += ["clamp_to_band", "forgetting_weight", "igg3_weights", "irakf_weights", "rae_rhat"]
