"""The frame every page draws first: page config, the page menu, presentation mode.

* The page menu (sidebar) links carry the experiment from one page to the next: the links to the
  run pages (Compare, Noise, Sweep, Tune) hold the last experiment's URL parameters
  (:func:`navlab.ui.widgets.spec_query`), so the experiment chosen on one page is the experiment
  on the next; on a run page they are drawn after its widgets (:func:`fill_nav`).
* Presentation mode (``?present=1`` on any page, carried by every link): large type, no sidebar,
  charts sized to fill a screen with every text ≥ 20 px, no download buttons, and the keyboard
  moves between charts (→ / PageDown / n next, ← / PageUp / p previous).
"""

from __future__ import annotations

import contextlib
import importlib.machinery
import sys
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
    ("pages/8_Leaderboard.py", "Leaderboard", "Leaderboard", ":material/leaderboard:"),
)
RUN_PAGES = ("pages/1_Compare.py", "pages/2_Noise.py", "pages/3_Sweep.py", "pages/7_Tune.py")
PRESENT = "present"  # the URL flag of presentation mode
PAGE_KEY = "_navlab_page"  # session: the title of the page the last script run drew
_run = threading.local()  # this script run's page-menu container (script runs are per thread)


def _warm() -> None:
    """Import and exercise the heavy paths once (plotly validators, a tiny run of the filters the
    Compare page opens with, so that their compiled kernels are loaded, or on a fresh install
    compiled, before the first Run).
    """
    try:
        from navlab.experiment import ExperimentSpec, run_experiment
        from navlab.scenarios.base import get_scenario_class
        from navlab.ui import figures as F

        spec = ExperimentSpec(runs=2, epochs=5)
        # not the app's streaming run (navlab.ui.runner): its cost model would learn a compile
        res = run_experiment(spec.replace(filters=get_scenario_class(spec.scenario).default_filters))
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


@st.cache_resource(show_spinner=False)
def warm_run_once(spec_json: str) -> threading.Thread:
    """Start a tiny run of ``spec_json`` (an ExperimentSpec) in the background, once per server
    process: a page whose runs need kernels the Compare page's filters do not (Real data: the INS
    model, IRAKF, …) compiles them on a fresh install while it is read, not after Run.
    """

    def run() -> None:
        with contextlib.suppress(Exception):  # best effort (a missing recording: nothing to warm)
            from navlab.experiment import ExperimentSpec, run_experiment

            run_experiment(ExperimentSpec.from_json(spec_json))

    t = threading.Thread(target=run, name="navlab-warm-page", daemon=True)
    t.start()
    return t


def presenting() -> bool:
    """Whether this page is shown in presentation mode (``?present=1``)."""
    with contextlib.suppress(Exception):  # no script run (a test calling a view directly)
        return str(st.query_params.get(PRESENT, "")).lower() in ("1", "true", "yes")
    return False


PRESENT_CSS = """
<style>
html { font-size: 22px; }
[data-testid="stSidebar"], [data-testid="stSidebarCollapsedControl"],
[data-testid="stExpandSidebarButton"], header[data-testid="stHeader"] { display: none !important; }
[data-testid="stMainBlockContainer"] { max-width: 100% !important; padding: 1rem 3rem 40vh 3rem; }
[data-testid="stPlotlyChart"] { scroll-margin-top: 0.5rem; }
h1 { font-size: 2.4rem !important; }
[data-testid="stDownloadButton"] { display: none !important; }
</style>
"""
# → / PageDown / n: the next chart to the top of the screen; ← / PageUp / p: the previous one
# (not while typing in a widget or moving a slider).
PRESENT_JS = """
<script>
(() => {
  if (window.__navlabPresent) return;
  window.__navlabPresent = true;
  const charts = () => Array.from(document.querySelectorAll('[data-testid="stPlotlyChart"]'))
    .filter(e => e.getBoundingClientRect().height > 0);
  document.addEventListener('keydown', ev => {
    const t = ev.target;
    if (ev.altKey || ev.ctrlKey || ev.metaKey) return;
    const typing = 'input, textarea, select, [role="slider"], [contenteditable="true"]';
    if (t && t.closest && t.closest(typing)) return;
    const d = ['ArrowRight', 'PageDown', 'n'].includes(ev.key) ? 1
      : ['ArrowLeft', 'PageUp', 'p'].includes(ev.key) ? -1 : 0;
    const cs = charts();
    if (!d || !cs.length) return;
    ev.preventDefault();
    const top = e => e.getBoundingClientRect().top;
    let i;
    if (d > 0) { i = cs.findIndex(e => top(e) > 40); if (i < 0) i = cs.length - 1; }
    else { const up = cs.filter(e => top(e) < -40); i = up.length ? cs.indexOf(up[up.length - 1]) : 0; }
    cs[i].scrollIntoView({block: 'start'});
    window.__navlabChart = i;
  });
})();
</script>
"""


def spawn_safe_main() -> None:
    """Name the running page's module ``__main__`` for multiprocessing.

    Streamlit runs each page as a fresh ``__main__`` module with the page's ``__file__`` and no
    ``__spec__``; a worker process started by "spawn" (the embedded Dask cluster's, a
    reproduction's) then ran that page again in bare mode, which filled the server log with
    "missing ScriptRunContext" warnings. A main module whose spec is named ``__main__`` is not run
    again in the worker (multiprocessing.spawn).
    """
    main = sys.modules.get("__main__")
    if main is not None and getattr(main, "__spec__", None) is None:
        main.__spec__ = importlib.machinery.ModuleSpec("__main__", None)


def frame(title: str, icon: str = "🧭", intro: str | None = None, *, experiment: bool = False) -> None:
    """Page config + title (+ an intro line) + page menu + sidebar footer. Call first on every page.

    ``experiment``: the page draws the shared experiment sidebar (its page menu is drawn after
    those widgets, so the links carry this page's experiment). The first page view of a server
    process also warms the plotting and filtering code in a background thread, so the first Run
    does not pay for cold imports.
    """
    spawn_safe_main()
    st.set_page_config(
        page_title=f"{title} · navlab",
        page_icon=icon,
        layout="wide",
        initial_sidebar_state="collapsed" if presenting() else "auto",
    )
    _warm_once()
    _run.hop = st.session_state.get(PAGE_KEY) not in (None, title)
    st.session_state[PAGE_KEY] = title
    if presenting():
        st.html(PRESENT_CSS + PRESENT_JS, unsafe_allow_javascript=True)
    # navlab's own page menu (config: client.showSidebarNavigation = false): Streamlit's legacy
    # pages/ menu would list the home page under its file name, "app"
    _run.nav = st.sidebar.container()
    _run.charts = 0
    if not experiment:
        fill_nav()
    st.sidebar.divider()
    st.title(title)
    if intro:
        st.caption(intro)
    st.sidebar.caption(
        "navlab — robust & adaptive Kalman filters, batched Monte Carlo. "
        "Every setting is in the URL: copy it to share the exact run."
    )


def plural(n: int, word: str) -> str:
    """'1 filter', '5 filters'."""
    return f"{n} {word}{'' if n == 1 else 's'}"


def arrived_from_another_page() -> bool:
    """Whether this script run is the first on this page after a run of another page (a hop by
    the page menu or a page link in this session; a new tab or a reload is no hop).
    """
    return bool(getattr(_run, "hop", False))


def next_chart_id() -> str:
    """A key unique within this script run (a streamed view draws the same chart per chunk)."""
    n = getattr(_run, "charts", 0) + 1
    _run.charts = n
    return f"_chart{n}"


def carried_query(path: str) -> dict:
    """The URL parameters a link to page ``path`` carries: the session's experiment (run pages)
    and presentation mode.
    """
    from navlab.ui.widgets import CARRY_KEY

    q = dict(st.session_state.get(CARRY_KEY) or {}) if path in RUN_PAGES else {}
    if presenting():
        q[PRESENT] = "1"
    return q


def fill_nav() -> None:
    """Draw this run's page menu (once) into the container :func:`frame` reserved."""
    nav = getattr(_run, "nav", None)
    _run.nav = None
    if nav is not None:
        page_links(nav, short=True)


def page_links(container=None, short: bool = False) -> None:
    """Links to the pages that exist (others' pages appear when their files are added), each
    carrying the session's experiment and presentation mode (:func:`carried_query`).
    """
    from pathlib import Path

    c = container if container is not None else st
    root = Path(__file__).resolve().parents[2]
    for path, label, title, icon in PAGES:
        if (root / path).exists():
            # a page file added after the server started is not registered yet: no link
            with contextlib.suppress(st.errors.StreamlitAPIException):
                c.page_link(
                    path, label=label if short else title, icon=icon, query_params=carried_query(path) or None
                )
