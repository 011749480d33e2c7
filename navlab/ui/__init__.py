"""navlab's Streamlit layer: the only package of navlab that may import streamlit.

Modules
-------
colors
    A stable colour per filter key (pure; same colour on every page).
figures
    Plotly figure builders, pure functions of :class:`navlab.experiment.Results` (no streamlit):
    error-vs-time with Monte Carlo spread bands, true R(t) vs R̂, NIS vs its χ² band, sweeps.
widgets
    Experiment configuration widgets built generically from the registries and
    :func:`navlab.params.describe`, bound to the URL (``bind="query-params"``), and the
    spec ⇄ widget-state mapping used by config upload.
runner
    Cached and streaming experiment runners (results keyed by the spec's JSON, bounded).
share
    Config JSON download/upload and CSV downloads.
frame
    The common page frame (page config, sidebar footer) every page calls first.

Pages stay short scripts: read widgets → build an ExperimentSpec → cached/streamed run → render.
Importing ``navlab.ui`` itself imports nothing heavy; import the submodules you need.
"""
