"""AppTest helpers shared by the page tests (streamlit.testing.v1, no browser).

Import them with ``from apphelpers import ...`` (not ``from conftest import``: when tests/app and
tests/e2e are collected together, the name ``conftest`` resolves to only one of the two).

``open_page(path, **query)`` starts the app at its entry point (app.py), sets query parameters
(the URL state), switches to the page and runs it; ``plotly_figs(at)`` returns the figure JSON of
every Plotly chart on the page. Keep runs tiny: the machine is shared.
"""

from __future__ import annotations

import json
from pathlib import Path

from streamlit.testing.v1 import AppTest

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT = 120  # seconds per script run (a loaded 2-CPU machine; small runs take ~1 s)

# a small, fast configuration (URL keys of navlab.ui.widgets)
SMALL = {"runs": "6", "sc.cv2d.epochs": "30", "flt": ["kf", "oracle-kf", "chi2-kf"]}


def _open(page: str | None = None, **query) -> AppTest:
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=TIMEOUT)
    for k, v in query.items():
        at.query_params[k] = v
    at.run()
    if page is not None:
        at.switch_page(page)
        for k, v in query.items():
            at.query_params[k] = v
        at.run()
    return at


def plotly_figs(at: AppTest) -> list[dict]:
    return [json.loads(el.proto.spec) for el in at.get("plotly_chart")]


def assert_progress_above_charts(at: AppTest) -> None:
    """The run's progress bar comes before the first chart in the main area (in sight after Run)."""

    def walk(node):
        yield node
        for k in sorted(getattr(node, "children", {}) or {}):
            yield from walk(node.children[k])

    kinds = [n.type for n in walk(at.main)]
    assert "progress" in kinds and kinds.index("progress") < kinds.index("plotly_chart"), kinds


def assert_clean(at: AppTest) -> None:
    """No exception element and no error message on the page."""
    assert not at.exception, [e.value for e in at.exception]
    assert not at.error, [e.value for e in at.error]


def main_rerun_in_child() -> str | None:
    """In a worker process: the page file multiprocessing ran again as ``__mp_main__`` (None: none)."""
    import sys

    return getattr(sys.modules.get("__mp_main__"), "__file__", None)
