"""navlab in a real browser: headless Debian Chromium against a real ``streamlit run``.

Deep links on a fresh server, the URL round-trip, five concurrent sessions, a broken config
upload, Stop and resume, the χ² lock-out note, and the charts of every page readable at a desktop
and a phone width (screenshots in tests/e2e/_artifacts/). Every page opening without an exception
is also checked by test_lecture.py (through the sidebar) and test_teach_browser.py (presentation
mode, and one run's downloads); what AppTest checks without a browser (tests/app) is not repeated.
Timings (Run → first chart) are appended to _artifacts/timings.jsonl.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest
from playwright.sync_api import Browser, Page, expect

from navlab.experiment import ExperimentSpec

T = 90_000  # ms; the machine is shared and runs may queue
CHART = '[data-testid="stPlotlyChart"]'
COMPARE_CHARTS = 4  # the three result charts and the single-run view below them (#16 item 1)
DRAWN = f"{CHART} .legendtext"  # Plotly has drawn a results figure (the preview has no legend)
COMPLETE = re.compile(r"\d+/\d+ runs \(complete\)")
SMALL = "runs=8&sc.cv2d.epochs=40&flt=kf&flt=oracle-kf&flt=chi2-kf"


@pytest.fixture
def browser_context_args(browser_context_args: dict) -> dict:
    return {**browser_context_args, "viewport": {"width": 1400, "height": 1000}, "accept_downloads": True}


def button(page: Page, name: str, exact: bool = True):
    """An app button by its label; never Streamlit's own header buttons (its "Stop" while running)."""
    return page.get_by_role("button", name=name, exact=exact).and_(page.locator("button:not([kind=header])"))


def settle(page: Page) -> None:
    """Wait until the page has a title and the script is no longer running."""
    expect(page.locator("h1").first).to_be_visible(timeout=T)
    expect(page.locator('[data-testid="stStatusWidget"]')).to_have_count(0, timeout=T)
    # widgets whose code is still loading are drawn as grey placeholders (lazy-loaded bundles)
    expect(page.locator('[data-testid^="stSkeleton"]')).to_have_count(0, timeout=T)


def assert_no_exception(page: Page) -> None:
    expect(page.locator('[data-testid="stException"]')).to_have_count(0)


def run_and_wait(page: Page, label: str = "Run") -> float:
    """Click Run; wait for the first drawn chart (returns seconds) and for completion."""
    t0 = time.monotonic()
    button(page, label).click()
    expect(page.locator(DRAWN).first).to_be_visible(timeout=T)
    first_chart = time.monotonic() - t0
    if label == "Run":
        expect(page.get_by_text(COMPLETE)).to_be_visible(timeout=T)
    settle(page)
    assert_no_exception(page)
    return first_chart


def log_timing(artifacts_dir: Path, **row) -> None:
    with (artifacts_dir / "timings.jsonl").open("a") as f:
        f.write(json.dumps({"when": time.strftime("%Y-%m-%dT%H:%M:%S"), **row}) + "\n")


def expect_value(page: Page, label: str, value: str) -> None:
    """The input labelled ``label`` shows ``value`` (retried: the page may still be updating)."""
    expect(page.get_by_label(label, exact=True)).to_have_value(value, timeout=T)


def test_deep_link_on_a_fresh_server(fresh_server: str, page: Page, artifacts_dir: Path):
    url = (
        f"{fresh_server}/Compare?runs=12&seed=7&flt=kf&flt=chi2-kf&noise=step"
        "&ns.step.factor=4&out=mixture&ol.mixture.contamination=0.2"
    )
    page.goto(url)
    settle(page)
    assert_no_exception(page)
    # the page, not the legacy raw-file-name fallback, and the configuration from the link
    expect(page.locator("h1").first).to_have_text("Compare filters")
    links = page.locator('[data-testid="stSidebar"] [data-testid="stPageLink"]')
    expect(links.filter(has_text="Compare")).to_be_visible()
    expect(links.filter(has_text="Home")).to_be_visible()  # not the entry point's file name
    expect(page.locator('[data-testid="stSidebarNav"]')).to_have_count(0)
    expect_value(page, "Monte Carlo runs", "12")
    expect_value(page, "Seed", "7")
    expect_value(page, "factor", "4")
    expect_value(page, "contamination", "0.2")
    ms = page.locator('[data-testid="stMultiSelect"]').first
    expect(ms).to_contain_text("kf")
    expect(ms).to_contain_text("chi2-kf")
    expect(ms).not_to_contain_text("oracle-kf")
    first = run_and_wait(page)
    expect(page.locator(CHART)).to_have_count(COMPARE_CHARTS, timeout=T)
    expect(page.get_by_text("12/12 runs (complete)")).to_be_visible()
    log_timing(
        artifacts_dir,
        test="deep_link_fresh",
        run_to_first_chart_s=round(first, 2),
        config="cv2d kf,chi2-kf 12 runs",
    )


def test_widget_change_updates_url_and_reload_restores(page: Page):
    page.goto("/Compare")
    settle(page)
    seed = page.get_by_label("Seed", exact=True)
    seed.fill("42")
    seed.press("Enter")
    page.wait_for_url(re.compile(r"[?&]seed=42"), timeout=T)
    runs = page.get_by_label("Monte Carlo runs", exact=True)
    runs.fill("33")
    runs.press("Enter")
    page.wait_for_url(re.compile(r"runs=33"), timeout=T)
    assert "seed=42" in page.url
    page.reload()
    settle(page)
    expect_value(page, "Seed", "42")
    expect_value(page, "Monte Carlo runs", "33")
    assert_no_exception(page)


def test_config_upload_round_trip_and_broken_file(page: Page, tmp_path: Path):
    page.goto("/Compare")
    settle(page)
    page.get_by_text("Load / save configuration").click()
    bad = tmp_path / "broken.json"
    bad.write_text('{"scenario": "cv2d", "runs": ')
    page.locator('[data-testid="stFileUploaderDropzoneInput"]').set_input_files(str(bad))
    expect(page.get_by_text(re.compile("Configuration not loaded: .*not valid JSON"))).to_be_visible(
        timeout=T
    )
    assert_no_exception(page)
    good = tmp_path / "good.json"
    good.write_text(ExperimentSpec(runs=21, seed=9, filters=("kf", "chi2-kf")).to_json())
    page.locator('[data-testid="stFileUploaderDropzoneInput"]').set_input_files(str(good))
    expect(page.get_by_text(re.compile("Loaded good.json"))).to_be_visible(timeout=T)
    page.wait_for_url(re.compile(r"runs=21"), timeout=T)
    expect_value(page, "Seed", "9")
    assert_no_exception(page)


SESSION_RUNS = 12  # small: the five runs overlap on the server all the same (all clicked first)


def test_five_sessions_run_at_once(browser: Browser, base_url: str, artifacts_dir: Path):
    """Five sessions run the default filters at once: each completes with its own seed, charts
    and metric table."""
    contexts = [
        browser.new_context(base_url=base_url, viewport={"width": 1300, "height": 900}) for _ in range(5)
    ]
    try:
        for c in contexts:
            c.set_default_timeout(T)
        pages = [c.new_page() for c in contexts]
        for i, p in enumerate(pages):
            p.goto(f"/Compare?runs={SESSION_RUNS}&seed={100 + i}")
        for p in pages:
            settle(p)
        t0 = time.monotonic()
        for p in pages:  # all five start before any is awaited
            button(p, "Run").click()
        done = f"{SESSION_RUNS}/{SESSION_RUNS} runs (complete)"
        for i, p in enumerate(pages):
            expect(p.get_by_text(done)).to_be_visible(timeout=3 * T)
            expect(p.locator(CHART)).to_have_count(COMPARE_CHARTS, timeout=T)
            expect(p.locator('[data-testid="stTable"]').first).to_be_visible()
            assert_no_exception(p)
            assert "seed=" + str(100 + i) in p.url
        log_timing(
            artifacts_dir,
            test="five_sessions",
            all_done_s=round(time.monotonic() - t0, 2),
            config=f"cv2d default filters {SESSION_RUNS} runs x 5 sessions",
        )
    finally:
        for c in contexts:
            c.close()


# slow enough that Stop lands while batches are still computing on a fast machine too (the
# default filters finished all 3000 runs in 1.4 s of compute on an AMD EPYC, before the click):
# chunks of 25, 325, 325 and 325 runs of the slow filters; a 325-run chunk computed for 2.3 s on
# this 2-core machine at a load of 3–4, so the click lands inside one and Run has ~650 runs left
SLOW_RUNS = 1000
SLOW_RUN = f"runs={SLOW_RUNS}&seed=21&flt=kf&flt=vb-ekf&flt=skew-t-kf&sc.cv2d.epochs=120"


def test_stop_keeps_partial_results_and_run_resumes(page: Page):
    page.goto(f"/Compare?{SLOW_RUN}")
    settle(page)
    button(page, "Run").click()
    expect(page.get_by_text(re.compile(rf"\d+/{SLOW_RUNS} runs \(partial\)"))).to_be_visible(timeout=T)
    # Stop beside Run (#16 item 5), pressed while a batch is in flight (the progress text
    # "N/1000 runs…" is shown only while one computes): that batch is kept, not thrown away
    inflight = page.get_by_text(re.compile(rf"^\d+/{SLOW_RUNS} runs…$"))
    expect(inflight).to_be_visible(timeout=T)
    at_click = int(inflight.inner_text().split("/")[0])
    stop = button(page, "Stop")
    run_box = button(page, "Run").bounding_box()
    stop_box = stop.bounding_box()
    assert abs(stop_box["y"] - run_box["y"]) < 20  # on the Run button's line
    stop.click()
    stopped = page.get_by_text(re.compile(rf"Stopped after \d+ of {SLOW_RUNS} runs"))
    expect(stopped).to_be_visible(timeout=T)
    settle(page)
    assert_no_exception(page)
    expect(page.locator(DRAWN).first).to_be_visible()  # the partial curves stay on the page
    done = int(re.search(r"after (\d+) of", stopped.inner_text()).group(1))
    assert at_click <= done < SLOW_RUNS  # the batch in flight at the click is among the runs kept
    button(page, "Run").click()  # resumes, does not restart
    expect(page.get_by_text(f"{SLOW_RUNS}/{SLOW_RUNS} runs (complete)")).to_be_visible(timeout=3 * T)
    settle(page)
    assert_no_exception(page)


# ------------------------------------------------------------------ readable charts (#11 item 5)
# Every page that draws charts, at a desktop and a phone width: no legend box may intersect a
# title (the figure's or a subplot's), the plot area, an axis title or a tick label; the R̂ chart
# is on a log axis. Per-chart screenshots go to _artifacts/charts-<page>-<width>-<i>.png, the whole
# page at the desktop width to _artifacts/page-<page>.png.
WIDTHS = (1440, 390)
NOISE_SMALL = "runs=6&flt=kf&flt=oracle-kf&flt=sage-husa&sc.cv2d.epochs=60"
CHART_PAGES = [
    # (name, path?query, button to press or None, charts expected once drawn,
    #  (part of the R̂ chart's title, its page's log toggle or None) or None: no R̂ chart)
    ("compare", f"Compare?{SMALL}", "Run", COMPARE_CHARTS, ("true R(t)", "log R")),
    ("noise", f"Noise?{NOISE_SMALL}", "Run", 2, ("true R(t)", "log scale")),
    ("sweep", "Sweep?runs=4&flt=kf&flt=chi2-kf&swn=3&sc.cv2d.epochs=40", "Run sweep", 2, None),
    # the claims, the rankings and 2 curves
    ("reproduce", "Reproduce?rep=vbekf&rep_seeds=1&rep_runs_vbekf=3", "Run", 4, None),
    ("learn", "Learn?filter=chi2-kf&ex_epochs=20&ex_noise=3", None, 1, None),
    ("realdata", "Real_data?rd_ep_drive0708=30", "Run", 4, ("√R̂", None)),
]
GEOMETRY_JS = r"""
() => Array.from(document.querySelectorAll('.js-plotly-plot')).map((gd, i) => {
  const boxes = sel => Array.from(gd.querySelectorAll(sel)).map(e => e.getBoundingClientRect())
    .filter(b => b.width > 0 && b.height > 0).map(b => [b.left, b.top, b.right, b.bottom]);
  const fl = gd._fullLayout || {};
  return {
    i, title: (fl.title && fl.title.text) || (fl.annotations || []).map(a => a.text).join(' | '),
    visible: gd.getBoundingClientRect().width > 0,
    yaxis: fl.yaxis ? fl.yaxis.type : null,
    legend: boxes('.legend > .bg'),
    others: {
      title: boxes('.g-gtitle text').concat(boxes('.annotation')),
      'plot area': boxes('.nsewdrag'),
      'axis title': boxes('[class^="g-x"][class$="title"] text, [class^="g-y"][class$="title"] text'),
      'tick label': boxes('.xtick text, .ytick text'),
    },
  };
})
"""


def _intersect(a, b, tol: float = 1.0) -> bool:
    return a[0] < b[2] - tol and b[0] < a[2] - tol and a[1] < b[3] - tol and b[1] < a[3] - tol


def legend_overlaps(charts: list[dict]) -> list[str]:
    """'chart i (title): legend overlaps <what>' for every legend box touching anything."""
    out = []
    for c in charts:
        for box in c["legend"]:
            for what, others in c["others"].items():
                if any(_intersect(box, o) for o in others):
                    out.append(f"chart {c['i']} ({c['title'][:60]!r}): legend overlaps the {what}")
    return out


def open_charts(page: Page, width: int, path: str, button_label, n: int) -> None:
    """``page`` at ``width`` px with its charts drawn (``button_label`` pressed first, if any)."""
    page.set_viewport_size({"width": width, "height": 1000})
    page.goto(f"/{path}")
    settle(page)
    if button_label:
        button(page, button_label).click()
    expect(page.locator(CHART)).to_have_count(n, timeout=T)
    page.wait_for_function(
        f"document.querySelectorAll('.js-plotly-plot .legend, .js-plotly-plot .g-gtitle').length >= {n}",
        timeout=T,
    )
    settle(page)
    page.wait_for_timeout(1000)  # a last batch's rerun may start just after the first settle
    settle(page)
    assert_no_exception(page)


def screenshot_charts(page: Page, path_of) -> None:
    """Each visible chart to ``path_of(i)`` (artifacts for a human): a chart redrawn between the
    locating and the shot (Streamlit replaces the element) is located again, up to three times."""
    from playwright.sync_api import Error

    for i in range(page.locator(f"{CHART}:visible").count()):
        for attempt in range(3):
            try:
                page.locator(f"{CHART}:visible").nth(i).screenshot(path=str(path_of(i)), timeout=T)
                break
            except Error:
                if attempt == 2:
                    raise
                settle(page)


def resize(page: Page, width: int) -> None:
    """The drawn page at ``width`` px: wait until Plotly has laid every chart out again. A page
    resized from 1440 to 390 px measured the same legend, plot-area and title boxes (up to the
    page's vertical offset) as the page opened at 390 px on Compare, Reproduce and Real data."""
    page.set_viewport_size({"width": width, "height": 1000})
    page.wait_for_function(
        "w => Array.from(document.querySelectorAll('.js-plotly-plot .main-svg'))"
        ".every(s => s.getBoundingClientRect().width <= w)",
        arg=width,
        timeout=T,
    )
    settle(page)
    page.wait_for_timeout(1000)  # a relayout may trigger one more rerun
    settle(page)
    assert_no_exception(page)


def _rhat_axis(page: Page, title_part: str) -> str:
    charts = page.evaluate(GEOMETRY_JS)
    (c,) = [c for c in charts if title_part in c["title"]]
    return c["yaxis"]


@pytest.mark.parametrize(
    ("name", "path", "button_label", "n", "rhat"), CHART_PAGES, ids=[p[0] for p in CHART_PAGES]
)
def test_no_legend_covers_a_title_or_the_data_and_rhat_is_log(
    page: Page, artifacts_dir: Path, name, path, button_label, n, rhat
):
    """One drawn page per chart page, at each of WIDTHS in turn (resized, not drawn again): no
    legend covers anything; the R̂ chart is on a log axis by default and follows its page's toggle."""
    if name == "realdata":
        from navlab.data import data_root
        from navlab.data.loaders import RTKX_DIR

        if not (data_root() / RTKX_DIR).is_dir():
            pytest.skip(f"real data not found under {data_root()} (set NAVLAB_DATA)")
    open_charts(page, WIDTHS[0], path, button_label, n)
    page.screenshot(path=str(artifacts_dir / f"page-{name}.png"), full_page=True)
    for width in WIDTHS:
        if width != WIDTHS[0]:
            resize(page, width)
        charts = [c for c in page.evaluate(GEOMETRY_JS) if c["visible"]]
        assert charts
        screenshot_charts(page, lambda i, w=width: artifacts_dir / f"charts-{name}-{w}-{i}.png")
        assert legend_overlaps(charts) == [], f"at {width} px"
    if rhat is None:
        return
    title_part, toggle = rhat
    assert _rhat_axis(page, title_part) == "log"
    if toggle is None:
        return
    switch = page.get_by_label(toggle, exact=True)
    expect(switch).to_be_checked(timeout=T)  # log by default
    page.get_by_text(toggle, exact=True).click()
    expect(switch).to_be_checked(checked=False, timeout=T)
    settle(page)
    page.wait_for_function(
        "part => Array.from(document.querySelectorAll('.js-plotly-plot')).some(gd => gd._fullLayout"
        " && gd._fullLayout.title && gd._fullLayout.title.text.includes(part)"
        " && gd._fullLayout.yaxis.type === 'linear')",
        arg=title_part,
        timeout=T,
    )


def test_lockout_is_explained_with_a_link_to_learn(page: Page, base_url: str):
    """#11 item 6: after an R step the χ²-gated KF's gate locks out; one sentence says so, with the
    number, next to the table, and links to the Learn page stepping through the mechanism."""
    page.set_default_timeout(T)
    page.goto("/Compare?runs=20&seed=1&flt=kf&flt=chi2-kf&noise=step&out=none")
    settle(page)
    run_and_wait(page)
    note = page.get_by_text(re.compile(r"gate lock-out in \d+ of 20 runs"))
    expect(note).to_be_visible(timeout=T)
    assert re.search(r"for \d+ consecutive epochs", note.inner_text())
    link = page.get_by_role("link", name="see how on Learn").first
    href = link.get_attribute("href")
    assert href and href.startswith("Learn?") and "filter=chi2-kf" in href
    page.goto(f"{base_url}/{href}")
    settle(page)
    assert_no_exception(page)
    expect(page.locator("h1").first).to_have_text(re.compile("Learn"), timeout=T)
    expect(page.get_by_role("heading", name="χ²-gated KF").first).to_be_visible(timeout=T)
