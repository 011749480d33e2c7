"""navlab home page (the Streamlit entry point; pages/ holds the other pages)."""

import streamlit as st

from navlab.scenarios import scenario_registry
from navlab.ui import home
from navlab.ui.frame import frame, page_links

frame(
    "navlab — robust & adaptive Kalman filters",
    intro="A lab for comparing Kalman filters when the measurement noise is unknown, changes over "
    "time or is contaminated by outliers: batched Monte Carlo in numpy, results in the browser.",
)

home.demo()  # full width: in the narrow right column its R̂ panels and their titles overlapped

left, right = st.columns([3, 2], gap="large")
with left:
    st.markdown(
        """
**What it does.** Pick filters, a scenario, a *noise schedule* (how the true measurement noise
R(t) changes over the run) and an *outlier model* (e.g. a contamination ratio α); navlab simulates
the same Monte Carlo runs for every filter, server-side and batched over runs, and shows the error
curves, the estimated R̂ against the true R(t), and filter consistency (NIS against its χ² band).
Every setting lives in the URL: copy it to share the exact run.

**The four papers navlab reproduces**
- **HAKF** — Zuo, Yin, Gao, Li 2017: variational-Bayes adaptive R plus Huber re-weighting for
  SINS/GPS under time-varying noise and Gaussian-mixture outliers.
- **IRAKF** — Ge, Zhang, Tang 2020: Sage–Husa windowed R estimation with IGG/Huber innovation
  weights and dual outlier detection, on 2-D target tracking (`cv2d`).
- **NNMFUKF** — Tan, Wang, Zhao 2015: SVD-UKF with multiple fading factors and an RBF network
  that replaces observations failing a χ² test, on GPS-RTK/INS.
- **VB-EKF** — Hou et al. 2024 (after Huang et al. 2018): EKF with inverse-Wishart adaptive P and R
  on GPS/INS with pseudoranges.
"""
    )
    st.subheader("Where to start")
    st.markdown(
        "1. **Compare** — run the default experiment (2-D tracking; the true noise σ steps up ×3 "
        "half-way) and watch the errors and each filter's R̂ fill in as batches of runs finish.\n"
        "2. **Noise** — follow each R̂ against the true R(t), channel by channel; one click adds "
        "isolated outliers, and most R̂ inflate.\n"
        "3. **Sweep** — vary the contamination ratio (or any parameter) and see where each "
        "filter breaks down."
    )
    page_links()
with right:
    sreg = scenario_registry()
    st.subheader("The filters, by family")
    home.filters_by_family()
    st.markdown(f"**{len(sreg)} scenarios:** " + ", ".join(f"`{k}`" for k in sreg))
    st.subheader("Data sources")
    st.markdown(
        """
- Simulated scenarios follow the papers (see `docs/ALGORITHMS.md` for the equations and defaults).
- **rtkx drive 0708** — car drive with a MEMS IMU and u-blox RTK, Boulder (rtklibexplorer/GNSS_IMU,
  BSD-3-Clause, © 2025 rtklibexplorer).
- **smartLoc Berlin Potsdamer Platz** — urban GPS/GLONASS pseudoranges with NovAtel SPAN ground
  truth (TU Chemnitz, via TUC-ProAut/libRSF; CC BY-SA 4.0).

The real data are not part of the repository; the app reads them from `../shared/data/` or the
folder named by `NAVLAB_DATA`.
"""
    )
    st.caption(
        "Command line: `python -m navlab list filters` · "
        "`python -m navlab run --scenario cv2d --filters kf,oracle-kf,chi2-kf --runs 100`"
    )
