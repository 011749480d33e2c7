"""Noise: how each adaptive filter's R̂ follows the true R(t), channel by channel."""

import streamlit as st

from navlab.ui.frame import frame, plural
from navlab.ui.runner import request_run, run_live, run_requested
from navlab.ui.share import config_download
from navlab.ui.sidebar import sidebar_experiment
from navlab.ui.views import NoiseView, noise_preset_button, show_stored
from navlab.ui.widgets import PageDefaults

PAGE = "noise"

frame(
    "Noise: R̂ inspection",
    "📈",
    "The true measurement noise R(t) of the schedule (black) against each filter's estimate "
    "R̂: median over runs and a 10–90 % band; a strip below marks the outlier epochs, when there are any.",
    experiment=True,
)

experiment = sidebar_experiment(PageDefaults(), "noise")  # planned once, run as it is
spec = experiment.spec

c1, c2, c3, c4 = st.columns([1, 2, 2, 3])
if c1.button("Run", type="primary", key="run_noise"):
    request_run(PAGE, spec)
config_download(spec, key="dl_cfg_noise", container=c2)
noise_preset_button(spec, c3)
c4.caption(
    f"{plural(len(spec.filters), 'filter')} × {spec.runs} runs · noise `{spec.noise_schedule}` · "
    f"outliers `{spec.outliers}`"
)

progress_box = st.container()  # the progress and Stop under Run, not below the last chart
view = NoiseView(PAGE)
if run_requested(PAGE, spec):
    run_live(experiment, PAGE, view.render, progress_container=progress_box, stop_container=progress_box)
else:
    show_stored(view, spec)
