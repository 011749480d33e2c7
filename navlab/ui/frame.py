"""The frame every page draws first: page config, sidebar footer, data/licence note."""

from __future__ import annotations

import contextlib
import threading

import streamlit as st

PAGES = (  # (file, sidebar label, title on the home page, icon)
    ("app.py", "Home", "Home", ":material/home:"),
    ("pages/1_Compare.py", "Compare", "Compare filters", ":material/compare_arrows:"),
    ("pages/2_Noise.py", "Noise (R̂)", "Noise: R̂ inspection", ":material/graphic_eq:"),
    ("pages/3_Sweep.py", "Sweep", "Sweep a parameter", ":material/tune:"),
    ("pages/7_Tune.py", "Tune", "Tune filters fairly", ":material/auto_fix_high:"),
    ("pages/4_Reproduce.py", "Reproduce", "Reproduce the papers", ":material/article:"),
    ("pages/5_Learn.py", "Learn", "Learn: filters step by step", ":material/school:"),
    ("pages/6_Real_data.py", "Real data", "Real data", ":material/directions_car:"),
)


def _warm() -> None:
    """Import and exercise the heavy paths once (plotly validators, every filter, a tiny run)."""
    try:
        from navlab.experiment import ExperimentSpec
        from navlab.ui import figures as F
        from navlab.ui.runner import iter_chunks

        for res in iter_chunks(ExperimentSpec(runs=2, epochs=5)):
            F.error_vs_time(res, "pos").to_json()
            F.r_vs_rhat(res, 0, outlier_strip=True).to_json()
            F.nis_vs_chi2(res).to_json()
    except Exception:  # warming is best effort; the real run reports any problem
        return


@st.cache_resource(show_spinner=False)
def _warm_once() -> threading.Thread:
    """Start warming in the background once per server process (first page view)."""
    t = threading.Thread(target=_warm, name="navlab-warm", daemon=True)
    t.start()
    return t


def frame(title: str, icon: str = "🧭", intro: str | None = None) -> None:
    """Page config + title (+ an intro line) + sidebar footer. Call first on every page.

    The first page view of a server process also warms the plotting and filtering code in a
    background thread, so the first Run does not pay for cold imports.
    """
    st.set_page_config(page_title=f"{title} · navlab", page_icon=icon, layout="wide")
    _warm_once()
    # navlab's own page menu (config: client.showSidebarNavigation = false): Streamlit's legacy
    # pages/ menu would list the home page under its file name, "app"
    page_links(st.sidebar, short=True)
    st.sidebar.divider()
    st.title(title)
    if intro:
        st.caption(intro)
    st.sidebar.caption(
        "navlab — robust & adaptive Kalman filters, batched Monte Carlo. "
        "Every setting is in the URL: copy it to share the exact run."
    )


def page_links(container=None, short: bool = False) -> None:
    """Links to the pages that exist (others' pages appear when their files are added)."""
    from pathlib import Path

    c = container if container is not None else st
    root = Path(__file__).resolve().parents[2]
    for path, label, title, icon in PAGES:
        if (root / path).exists():
            # a page file added after the server started is not registered yet: no link
            with contextlib.suppress(st.errors.StreamlitAPIException):
                c.page_link(path, label=label if short else title, icon=icon)
