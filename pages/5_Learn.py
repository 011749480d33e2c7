"""Learn: each filter's idea, equations and paper, and a step-through of single updates."""

import streamlit as st

from navlab.learn import TinySpec
from navlab.ui import learn as ui
from navlab.ui.frame import frame

frame(
    "Learn: filters step by step",
    ":material/school:",
    "Pick a filter: its idea, its key equations and the paper, then step through its updates on "
    "a tiny constant-velocity example with an outlier you place. The URL keeps the filter, the "
    "example and the step, so a link shows the same update.",
)

# Widget keys are page-specific (session_state is shared by all pages; other pages use
# flt/runs/seed). Widget defaults live in session_state (no value= on the widgets): the URL
# still initialises them (bind="query-params"), and the ◀/▶ buttons and range clamping can move
# them freely.
DEFAULTS = {
    "filter": "kf",
    "ex_dims": "1-D",
    "ex_epochs": 8,
    "ex_outk": 5,
    "ex_outsize": 10.0,
    "ex_outall": False,
    "ex_noise": 1.0,
    "ex_seed": 0,
    "step": 1,
    "lmode": "One filter",
    "cmp": ["kf", "huber-kf"],
}
for k, v in DEFAULTS.items():
    st.session_state.setdefault(k, v)

keys = ui.filter_keys()
if not keys:
    st.info("No filters are registered.")
    st.stop()
if st.session_state["filter"] not in keys:
    st.session_state["filter"] = keys[0]
mode = (
    st.segmented_control(
        "View",
        ["One filter", "Side by side"],
        key="lmode",
        bind="query-params",
        help="side by side: two or three filters on the same tiny example and the same outlier, "
        "stepped together",
    )
    or "One filter"
)
if mode == "Side by side":
    ok = [k for k in st.session_state["cmp"] if k in keys][:3]
    if ok != list(st.session_state["cmp"]):
        st.session_state["cmp"] = ok or keys[:2]
    compared = st.multiselect(
        "Filters side by side (2 or 3)",
        keys,
        key="cmp",
        max_selections=3,
        bind="query-params",
        format_func=lambda k: f"{k} — {ui.registry()[k].label}",
    )
    key = compared[0] if compared else keys[0]
else:
    compared = []
    # no format_func: a bound selectbox puts the formatted option in the URL; keys keep it short
    key = st.selectbox("Filter (registry key)", keys, key="filter", bind="query-params")
    ui.render_filter_card(key)

st.divider()
st.subheader("Step through single updates")
with st.expander("The tiny example", expanded=True):
    c1, c2, c3 = st.columns(3)
    dims = (
        c1.segmented_control(
            "Model",
            ["1-D", "2-D"],
            key="ex_dims",
            bind="query-params",
            help="1-D: state [p, v], p measured; 2-D: state [x, y, v_x, v_y], x and y measured",
        )
        or "1-D"
    )
    epochs = c1.slider("Epochs", 2, 30, key="ex_epochs", bind="query-params")
    if st.session_state["ex_outk"] > epochs:
        st.session_state["ex_outk"] = epochs
    oe = c2.slider("Outlier at epoch (0 = none)", 0, epochs, key="ex_outk", bind="query-params")
    os_ = c2.slider(
        "Outlier size (measurement σ)",
        -30.0,
        30.0,
        step=0.5,
        key="ex_outsize",
        bind="query-params",
    )
    oall = c2.checkbox(
        "Outlier on every channel",
        key="ex_outall",
        bind="query-params",
        help="Otherwise only the first channel (p or x) is hit.",
    )
    ns = c3.slider(
        "True noise σ / assumed σ",
        0.25,
        5.0,
        step=0.25,
        key="ex_noise",
        bind="query-params",
        help="Above 1 the filters' R is too small: watch the adaptive filters' R̂ grow.",
    )
    seed = c3.number_input("Noise seed", 0, 10_000, step=1, key="ex_seed", bind="query-params")

spec = TinySpec(
    dims=2 if dims == "2-D" else 1,
    epochs=int(epochs),
    outlier_epoch=int(oe),
    outlier_size=float(os_),
    outlier_channel="all" if oall else "first",
    noise_scale=float(ns),
    seed=int(seed),
)
if mode == "Side by side":
    ui.render_side_by_side(compared, spec)
else:
    ui.render_one(key, spec)
ui.compare_link(compared or [key], spec)

with st.expander("Which filters can run on the tiny example?"):
    st.dataframe(ui.cached_applicability(spec), hide_index=True, width="stretch")
