"""The home page's pieces: a one-click demo and the filters listed by family."""

from __future__ import annotations

import streamlit as st

from navlab.filters import registry
from navlab.ui import figures as F
from navlab.ui.runner import run_live
from navlab.ui.views import chart, rhat_chart
from navlab.ui.widgets import default_spec, spec_query

# the experiment every run page opens on, at 50 runs (≈ 0.3 s of compute on this machine)
DEMO = default_spec(runs=50)
DEMO_KEY = "_navlab_home_demo"
FAMILIES = (  # (family key, heading, what the family does)
    ("baseline", "Baselines", "the textbook filters everything is compared with"),
    ("oracle", "Oracle", "knows what no real filter can: the accuracy floor"),
    ("robust", "Robust", "resist outliers with a fixed R"),
    ("adaptive", "Adaptive", "estimate the measurement noise R̂ as it changes"),
    ("robust-adaptive", "Robust and adaptive", "both at once: the papers' proposals"),
    ("nonlinear", "Nonlinear", "for models that are not linear"),
)


def demo() -> None:
    """A button that runs a small experiment and shows its errors and R̂ within seconds."""
    st.subheader("See it in seconds")
    if st.button(
        f"▶ Run the demo: {len(DEMO.filters)} filters, {DEMO.runs} runs, the true σ steps ×3",
        type="primary",
        key="home_demo",
        help="2-D target tracking; the KF, three filters that estimate R (Sage–Husa, VB, VB + Huber) "
        "and the oracle that is handed the true R(t)",
    ):
        st.session_state[DEMO_KEY] = True
    if not st.session_state.get(DEMO_KEY):
        st.caption(
            "One click: the same Monte Carlo runs for every filter; the error over time, and each "
            "filter's estimate R̂ of the measurement noise against the true R(t)."
        )
        return
    res = run_live(DEMO, "home", stop_button=False)
    if res is None:
        return
    chart(st, F.error_vs_time(res, "pos"), "demo: position error over time per filter", name="demo-error")
    rhat_chart(st, res, 0, F.r_vs_rhat(res, 0))
    st.page_link(
        "pages/1_Compare.py",
        label="Open this experiment in Compare (table, R̂, consistency, one run)",
        icon=":material/compare_arrows:",
        query_params={**spec_query(DEMO), "go": "1"},
    )


def filters_by_family() -> None:
    """Every registered filter under its family's heading, one line each."""
    reg = registry()
    known = {f for f, _, _ in FAMILIES}
    groups = list(FAMILIES) + [
        (f, f.capitalize(), "") for f in sorted({c.family for c in reg.values()} - known)
    ]
    for fam, head, what in groups:
        keys = [k for k, c in reg.items() if c.family == fam]
        if not keys:
            continue
        lines = "\n".join(f"- **{reg[k].label}** (`{k}`) — {reg[k].summary}" for k in keys)
        st.markdown(f"**{head}**" + (f" — {what}" if what else "") + "\n" + lines)
