"""A lecture, walked in a real browser at 1440×900: a shared link with non-default filters and
schedule, then every page through the sidebar (issue #21, "the first five minutes").

On every page: the experiment is the link's (the address bar, and the sidebar's widgets on the run
pages); no table needs sideways scrolling and no table cell reads None or NaN. On the pages about
R̂ (Compare, Noise): an adaptive filter's R̂ trace is drawn apart from the true R(t).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from playwright.sync_api import Error as PlaywrightError
from playwright.sync_api import Page, expect
from playwright.sync_api import TimeoutError as PlaywrightTimeoutError

from tests.e2e.test_browser import COMPLETE, T, button, settle

# non-default filters, schedule, runs and seed (the defaults: kf, sage-husa, vb-akf, hakf,
# oracle-kf on the step schedule, 100 runs, seed 1)
LINK = {
    "flt": ["kf", "vb-akf", "hakf", "oracle-kf"],
    "runs": "12",
    "seed": "7",
    "noise": "burst",
    "sc.cv2d.epochs": "60",
}
QUERY = "&".join(f"{k}={v}" for k, vs in LINK.items() for v in ([vs] if isinstance(vs, str) else vs))
# (sidebar label, page path, a run page: the experiment's widgets are on it)
WALK = [
    ("Noise (R̂)", "Noise", True),
    ("Sweep", "Sweep", True),
    ("Tune", "Tune", True),
    ("Reproduce", "Reproduce", False),
    ("Learn", "Learn", False),
    ("Real data", "Real_data", False),
    ("Home", "", False),
    ("Compare", "Compare", True),
]
TABLES = '[data-testid="stTable"], [data-testid="stDataFrame"] .dvn-scroller'
CELLS = (
    '[data-testid="stTable"] td, [data-testid="stTable"] th, [data-testid="stDataFrame"] [role="gridcell"]'
)
BAD_CELL = re.compile(r"^\s*(None|nan|NaN|<NA>)\s*$")
# the sidebar's first link to Compare carries every wanted "key=value" of the link
COMPARE_LINK_CARRIES = """wanted => {
  const compare = Array.from(document.querySelectorAll('[data-testid="stSidebar"] a'))
    .map(e => e.href).filter(h => h.includes('/Compare'));
  return compare.length > 0 && wanted.every(w => compare[0].includes(w));
}"""


@pytest.fixture
def browser_context_args(browser_context_args: dict) -> dict:
    return {**browser_context_args, "viewport": {"width": 1440, "height": 900}}


def assert_link_experiment(page: Page, run_page: bool) -> None:
    """The address bar (run pages) and the sidebar's links carry the link's experiment."""
    wanted = [f"{k}={v}" for k, vs in LINK.items() for v in ([vs] if isinstance(vs, str) else vs)]
    if run_page:
        expect(page).to_have_url(re.compile(re.escape("seed=7")), timeout=T)
        url = page.url
        assert all(w in url for w in wanted), f"{url} lost some of {wanted}"
        chips = page.locator('[data-testid="stSidebar"] [data-testid="stMultiSelect"]').first.inner_text()
        for f in LINK["flt"]:
            assert f in chips, f"the sidebar's filters {chips!r} are not the link's"
    # retried: just after a sidebar click the new page's script run redraws the sidebar, and for a
    # moment it has no Compare link (seen once on a loaded machine: "the Compare link []")
    try:
        page.wait_for_function(COMPARE_LINK_CARRIES, arg=wanted, timeout=T)
    except PlaywrightError:
        hrefs = page.locator('[data-testid="stSidebar"] a').evaluate_all("els => els.map(e => e.href)")
        compare = [h for h in hrefs if "/Compare" in h]
        raise AssertionError(f"the Compare link {compare} lost the experiment") from None


def assert_tables_fit_and_are_clean(page: Page, where: str) -> None:
    """No table scrolls sideways in its container; no cell reads None or NaN."""
    wide = page.evaluate(
        """sel => Array.from(document.querySelectorAll(sel))
            .filter(e => e.getBoundingClientRect().width > 0)
            .filter(e => e.scrollWidth > e.clientWidth + 2)
            .map(e => (e.getAttribute('data-testid') || e.className) + ' ' + e.scrollWidth + '>'
                      + e.clientWidth)""",
        TABLES,
    )
    assert not wide, f"{where}: tables that scroll sideways: {wide}"
    cells = page.evaluate("sel => Array.from(document.querySelectorAll(sel)).map(e => e.innerText)", CELLS)
    bad = [c for c in cells if BAD_CELL.match(c)]
    assert not bad, f"{where}: cells reading None/NaN: {bad[:5]}"


# names of the adaptive filters' R̂ traces (not the oracle's) drawn in the page that differ from
# the true R(t) by more than 5 % somewhere: drawn apart from the truth, not hidden under it
RHAT_APART = """() => {
      const out = [];
      for (const el of document.querySelectorAll('[data-testid="stPlotlyChart"] .js-plotly-plot')) {
        const data = el._fullData || [];  // decoded arrays (el.data holds base64)
        const truth = data.find(t => (t.name || '').startsWith('true R(t)')
                                     && t.line && t.line.color !== '#ffffff');
        if (!truth) continue;
        const tx = Array.from(truth.x), ty = Array.from(truth.y);
        for (const t of data) {
          const name = t.name || '';
          if (!name.endsWith('R̂') || name.startsWith('Oracle')) continue;
          const y = Array.from(t.y), x = Array.from(t.x);
          let apart = false;
          for (let i = 0; i < x.length; i++) {
            const j = tx.findIndex(v => Math.abs(v - x[i]) < 1e-6);
            if (j >= 0 && isFinite(y[i]) && Math.abs(y[i] / ty[j] - 1) > 0.05) { apart = true; break; }
          }
          if (apart) out.push(name);
        }
      }
      return out;
    }"""
ADAPTIVE_APART = f"() => ({RHAT_APART})().some(n => n.startsWith('AKF (VB)') || n.startsWith('HAKF'))"


def assert_rhat_apart_from_truth(page: Page) -> None:
    """An adaptive filter's R̂ trace is drawn apart from the true R(t). Plotly draws the charts
    after the script has finished (and again when Streamlit replaces them), so the check waits
    for a drawn chart where it holds, up to T, and names the traces it found if none does.
    """
    try:
        page.wait_for_function(ADAPTIVE_APART, timeout=T, polling=250)
    except PlaywrightTimeoutError:
        raise AssertionError(f"R̂ traces apart from the truth: {page.evaluate(RHAT_APART)}") from None


def test_a_lecture_keeps_the_link_on_every_page(page: Page, artifacts_dir: Path):
    shots = artifacts_dir / "lecture"
    shots.mkdir(parents=True, exist_ok=True)
    page.goto(f"/Compare?{QUERY}")
    settle(page)
    assert_link_experiment(page, True)
    done: set[str] = set()  # the R̂ pages run once
    for i, (label, path, run_page) in enumerate([("Compare", "Compare", True), *WALK]):
        if i:  # the first page is the link's own
            page.locator('[data-testid="stSidebar"]').get_by_role("link", name=label, exact=True).click()
            expect(page).to_have_url(re.compile(rf"/{path}(\?|$)"), timeout=T)
            settle(page)
        assert_link_experiment(page, run_page)
        if label in ("Compare", "Noise (R̂)") and path not in done:
            done.add(path)
            button(page, "Run").click()
            expect(page.get_by_text(COMPLETE).first).to_be_visible(timeout=T)
            expect(page.get_by_text("What to look at.").first).to_be_visible(timeout=T)
            settle(page)
            assert_rhat_apart_from_truth(page)
            assert_link_experiment(page, run_page)
        assert_tables_fit_and_are_clean(page, label)
        expect(page.locator('[data-testid="stException"]')).to_have_count(0)
        page.screenshot(path=str(shots / f"{path or 'Home'}.png"))
