"""navlab in a real browser: headless Debian Chromium against a real ``streamlit run``.

Deep links on a fresh server, a run with charts, URL round-trip, downloads, five concurrent
sessions, a broken config upload, and a screenshot of every page (tests/e2e/_artifacts/).
Timings (Run → first chart) are appended to _artifacts/timings.jsonl.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pandas as pd
import pytest
from playwright.sync_api import Browser, Page, expect

from navlab.experiment import ExperimentSpec

T = 90_000  # ms; the machine is shared and runs may queue
CHART = '[data-testid="stPlotlyChart"]'
DRAWN = f"{CHART} .legendtext"  # Plotly has drawn a results figure (the preview has no legend)
COMPLETE = re.compile(r"\d+/\d+ runs \(complete\)")
SMALL = "runs=8&sc.cv2d.epochs=40"
ROOT = Path(__file__).resolve().parents[2]


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
        "&ns.step.factor=4&ol.mixture.contamination=0.2"
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
    expect(page.locator(CHART)).to_have_count(3, timeout=T)
    expect(page.get_by_text("12/12 runs (complete)")).to_be_visible()
    log_timing(
        artifacts_dir,
        test="deep_link_fresh",
        run_to_first_chart_s=round(first, 2),
        config="cv2d kf,chi2-kf 12 runs",
    )


def test_default_compare_run_and_timing(page: Page, artifacts_dir: Path):
    """The default configuration (cv2d, 100 runs, kf/oracle-kf/chi2-kf): Run → charts."""
    page.goto("/Compare")
    settle(page)
    first = run_and_wait(page)
    expect(page.locator(CHART)).to_have_count(3, timeout=T)
    expect(page.get_by_text("100/100 runs (complete)")).to_be_visible()
    cap = page.get_by_text(re.compile(r"done: 100 runs, [\d.]+ s compute")).inner_text()
    compute = float(re.search(r"([\d.]+) s compute", cap).group(1))
    log_timing(
        artifacts_dir,
        test="default_compare",
        run_to_first_chart_s=round(first, 2),
        server_compute_s=compute,
        config="cv2d default 3 filters 100 runs",
    )
    # the table lists every filter
    expect(page.locator('[data-testid="stDataFrame"]').first).to_be_visible()


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


def test_downloads_parse(page: Page):
    page.goto(f"/Compare?{SMALL}&seed=3")
    settle(page)
    run_and_wait(page)
    with page.expect_download(timeout=T) as d:
        button(page, "Configuration (JSON)", exact=False).click()
    spec = ExperimentSpec.from_json(Path(d.value.path()).read_text())
    assert spec.runs == 8 and spec.seed == 3 and spec.scenario_params == {"epochs": 40}
    assert spec.filters == ("kf", "oracle-kf", "chi2-kf")
    with page.expect_download(timeout=T) as d:
        button(page, "Metrics (CSV)", exact=False).click()
    df = pd.read_csv(d.value.path())
    assert {"filter", "metric", "value", "unit"} <= set(df.columns)
    assert set(df["filter"]) == {"kf", "oracle-kf", "chi2-kf"}
    assert (df[df.metric == "runs"].value == 8).all()
    with page.expect_download(timeout=T) as d:
        button(page, "RMSE per epoch (CSV)", exact=False).click()
    curves = pd.read_csv(d.value.path())
    assert {"filter", "group", "epoch", "rmse"} <= set(curves.columns)
    assert curves.epoch.max() == 40


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


def test_five_sessions_run_at_once(browser: Browser, base_url: str, artifacts_dir: Path):
    contexts = [
        browser.new_context(base_url=base_url, viewport={"width": 1300, "height": 900}) for _ in range(5)
    ]
    try:
        for c in contexts:
            c.set_default_timeout(T)
        pages = [c.new_page() for c in contexts]
        for i, p in enumerate(pages):
            p.goto(f"/Compare?runs=30&seed={100 + i}")
        for p in pages:
            settle(p)
        t0 = time.monotonic()
        for p in pages:  # all five start before any is awaited
            button(p, "Run").click()
        for i, p in enumerate(pages):
            expect(p.get_by_text("30/30 runs (complete)")).to_be_visible(timeout=3 * T)
            expect(p.locator(CHART)).to_have_count(3, timeout=T)
            assert_no_exception(p)
            assert "seed=" + str(100 + i) in p.url
        log_timing(artifacts_dir, test="five_sessions", all_done_s=round(time.monotonic() - t0, 2))
    finally:
        for c in contexts:
            c.close()


PAGES = [
    ("", "home", None, None),
    ("Compare", "compare", SMALL, "Run"),
    ("Noise", "noise", "runs=6&flt=kf&flt=oracle-kf&flt=sage-husa", "Run"),
    ("Sweep", "sweep", "runs=4&flt=kf&flt=chi2-kf&swn=3&sc.cv2d.epochs=40", "Run sweep"),
]
OTHER_PAGES = [p.stem.split("_", 1)[1] for p in sorted((ROOT / "pages").glob("[4-9]_*.py"))]


@pytest.mark.parametrize(("path", "name", "query", "button"), PAGES, ids=[p[1] for p in PAGES])
def test_page_renders_and_screenshot(page: Page, artifacts_dir: Path, path, name, query, button):
    page.goto(f"/{path}" + (f"?{query}" if query else ""))
    settle(page)
    assert_no_exception(page)
    if button:
        run_and_wait(page, button)
    page.screenshot(path=str(artifacts_dir / f"page-{name}.png"), full_page=True)


@pytest.mark.parametrize("path", OTHER_PAGES)
def test_other_pages_render_and_screenshot(page: Page, artifacts_dir: Path, path: str):
    """Pages other engineers own: they open without an exception (screenshot for humans)."""
    page.goto(f"/{path}")
    settle(page)
    assert_no_exception(page)
    page.screenshot(path=str(artifacts_dir / f"page-{path.lower()}.png"), full_page=True)


def test_stop_keeps_partial_results_and_run_resumes(page: Page):
    page.goto("/Compare?runs=3000&seed=21")
    settle(page)
    button(page, "Run").click()
    expect(page.get_by_text(re.compile(r"\d+/3000 runs \(partial\)"))).to_be_visible(timeout=T)
    button(page, "Stop").click()
    stopped = page.get_by_text(re.compile(r"Stopped after \d+ of 3000 runs"))
    expect(stopped).to_be_visible(timeout=T)
    settle(page)
    assert_no_exception(page)
    expect(page.locator(DRAWN).first).to_be_visible()  # the partial curves stay on the page
    done = int(re.search(r"after (\d+) of", stopped.inner_text()).group(1))
    assert 0 < done < 3000
    button(page, "Run").click()  # resumes, does not restart
    expect(page.get_by_text("3000/3000 runs (complete)")).to_be_visible(timeout=3 * T)
    settle(page)
    assert_no_exception(page)
