"""Compare: several filters on the same Monte Carlo data, streamed in as batches of runs finish."""

import streamlit as st

from navlab.metrics import summarize
from navlab.ui import figures as F
from navlab.ui.frame import frame
from navlab.ui.runner import request_run, run_live, run_requested
from navlab.ui.share import config_download, csv_download
from navlab.ui.views import CompareView, show_stored
from navlab.ui.widgets import PageDefaults, sidebar_experiment

PAGE = "compare"

frame(
    "Compare filters",
    "⚖️",
    "Every chosen filter runs on the same simulated measurements. Set the experiment in the "
    "sidebar, press Run; the curves update as batches of Monte Carlo runs finish.",
    experiment=True,
)

spec = sidebar_experiment(PageDefaults(), "compare")

c1, c2, c3, c4 = st.columns([1, 1, 1, 3])
if c1.button("Run", type="primary", key="run_compare"):
    request_run(PAGE, spec)
config_download(spec, key="dl_cfg_compare", container=c2)
live = c3.toggle(
    "Live updates",
    value=True,
    key="compare_live",
    help="redraw as batches of runs finish (Stop possible between batches); a "
    "run expected to be short, or whose first batch would cost most of the "
    "whole, is one batch anyway. Off: always one "
    "batch, which is faster because every batch pays the per-epoch overhead "
    "of every filter once",
)
c4.caption(
    f"{len(spec.filters)} filters × {spec.runs} runs · seed {spec.seed} · "
    f"noise `{spec.noise_schedule}` · outliers `{spec.outliers}`"
)

view = CompareView(PAGE)
if run_requested(PAGE, spec):
    view.live = True
    res = run_live(spec, PAGE, view.render, first_chunk=None if live else spec.runs)
    view.live = False
else:
    res = show_stored(view, spec)

if res is not None and res.complete:
    st.markdown("##### Downloads")
    d1, d2, _ = st.columns([1, 1, 3])
    csv_download(
        lambda: summarize(res, compare_to=view.ref),
        "Metrics (CSV)",
        "navlab-metrics.csv",
        "dl_metrics_compare",
        container=d1,
    )
    csv_download(
        lambda: F.rmse_curves(res),
        "RMSE per epoch (CSV)",
        "navlab-rmse-per-epoch.csv",
        "dl_curves_compare",
        container=d2,
    )
