"""Compare: several filters on the same Monte Carlo data, streamed in as batches of runs finish."""

import streamlit as st

from navlab.ui import single
from navlab.ui.frame import frame, plural
from navlab.ui.runner import request_run, run_live, run_requested
from navlab.ui.share import config_download, run_on_open
from navlab.ui.sidebar import sidebar_experiment
from navlab.ui.views import CompareView, headline_groups, run_downloads, show_stored
from navlab.ui.widgets import PageDefaults

PAGE = "compare"

frame(
    "Compare filters",
    "⚖️",
    "Every chosen filter runs on the same simulated measurements. Set the experiment in the "
    "sidebar, press Run; the curves update as batches of Monte Carlo runs finish.",
    experiment=True,
)

experiment = sidebar_experiment(PageDefaults(), PAGE)  # planned once, run as it is
spec = experiment.spec

# Run, Stop and the progress on one line, above the charts
c1, c2, c3 = st.columns([1, 1, 6], vertical_alignment="center")
if c1.button("Run", type="primary", key="run_compare") or run_on_open(PAGE, spec):
    request_run(PAGE, spec)
stop_box, progress_box = c2.empty(), c3.container()
o1, o2, o3 = st.columns([1, 1, 4], vertical_alignment="center")
config_download(spec, key="dl_cfg_compare", container=o1)
live = o2.toggle(
    "Live updates",
    value=True,
    key="compare_live",
    help="redraw as batches of runs finish (Stop possible between batches); a "
    "run expected to be short, or whose first batch would cost most of the "
    "whole, is one batch anyway. Off: always one "
    "batch, which is faster because every batch pays the per-epoch overhead "
    "of every filter once",
)
o3.caption(
    f"{plural(len(spec.filters), 'filter')} × {spec.runs} runs · seed {spec.seed} · "
    f"noise `{spec.noise_schedule}` · outliers `{spec.outliers}`"
)

view = CompareView(PAGE)
if run_requested(PAGE, spec):
    view.live = True
    res = run_live(
        experiment,
        PAGE,
        view.render,
        first_chunk=None if live else spec.runs,
        progress_container=progress_box,
        stop_container=stop_box,
    )
    view.live = False
else:
    res = show_stored(view, spec)

if res is not None and res.complete:
    group = view.group if view.group in res.data.groups else headline_groups(res)[0]
    single.render(res, PAGE, group)
    st.markdown("##### Downloads")
    run_downloads(res, view, group, PAGE)
