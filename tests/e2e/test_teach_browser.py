"""#16 in a real browser: the single-run view and its player, Learn side by side, presentation
mode on every page, settings carried from Compare to Noise, and every download of one run: the
configuration, the CSVs, the SVG and PNG figure, the script, and the notebook executed (nbclient)
reproducing the run's RMSE. What needs no browser is AppTest's
(tests/app/test_compare_page.py: choosing the single run's number, a rejected link value's notice).
"""

from __future__ import annotations

import json
import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pandas as pd
import pytest
from playwright.sync_api import Page, expect
from test_browser import CHART, COMPLETE, SMALL, T, assert_no_exception, button, expect_value, settle

from navlab.experiment import ExperimentSpec

ROOT = Path(__file__).resolve().parents[2]
ONE_RUN = f"{CHART}:has(.updatemenu-button)"  # the single-run chart (it has the play button)


@pytest.fixture
def browser_context_args(browser_context_args: dict) -> dict:
    return {**browser_context_args, "viewport": {"width": 1400, "height": 1000}, "accept_downloads": True}


def wait_complete(page: Page) -> None:
    expect(page.get_by_text(COMPLETE)).to_be_visible(timeout=T)
    settle(page)
    assert_no_exception(page)


def test_single_run_view_plays_one_run(page: Page):
    page.goto(f"/Compare?{SMALL}&seed=41&go=1")  # go=1: runs on open (the Learn and Home links)
    wait_complete(page)
    chart = page.locator(ONE_RUN)
    expect(chart).to_have_count(1, timeout=T)
    chart.scroll_into_view_if_needed()
    expect(chart.locator(".gtitle")).to_contain_text("Monte Carlo run", timeout=T)
    active = (
        "() => { const gd = Array.from(document.querySelectorAll('.js-plotly-plot'))"
        ".find(g => g.querySelector('.updatemenu-button')); return gd.layout.sliders[0].active; }"
    )
    n = page.evaluate(
        "() => Array.from(document.querySelectorAll('.js-plotly-plot'))"
        ".find(g => g.querySelector('.updatemenu-button')).layout.sliders[0].steps.length"
    )
    assert n == 40 and page.evaluate(active) == n - 1  # the whole run revealed
    chart.locator(".updatemenu-button").filter(has_text="play").click()
    page.wait_for_function(f"({active})() < {n - 5}", timeout=T)  # it restarted from the first epoch
    page.wait_for_function(f"({active})() === {n - 1}", timeout=T)  # and plays to the end
    assert_no_exception(page)


def test_learn_side_by_side_with_play(page: Page):
    page.goto("/Learn?lmode=Side+by+side&cmp=kf&cmp=huber-kf&step=1&ex_epochs=6")
    settle(page)
    assert_no_exception(page)
    expect(page.locator(CHART)).to_have_count(1, timeout=T)
    expect(page.locator(f"{CHART} .legendtext").filter(has_text="HKF (Huber)")).to_have_count(1, timeout=T)
    expect(page.get_by_text("Epoch 1, every filter after its update")).to_be_visible(timeout=T)
    button(page, "▶ play").click()
    expect(page.get_by_text("Epoch 3, every filter after its update")).to_be_visible(timeout=T)
    expect(page.get_by_text("Epoch 6, every filter after its update")).to_be_visible(timeout=T)
    page.wait_for_url(re.compile(r"step=6"), timeout=T)
    expect(button(page, "▶ play")).to_be_visible(timeout=T)  # stopped at the last step
    assert_no_exception(page)


PRESENT_PAGES = ["", "Compare", "Noise", "Sweep", "Tune", "Reproduce", "Learn", "Real_data"]


@pytest.mark.parametrize("path", PRESENT_PAGES, ids=[p or "home" for p in PRESENT_PAGES])
def test_every_page_works_in_presentation_mode(page: Page, path: str, artifacts_dir: Path):
    page.goto(f"/{path}?present=1")
    settle(page)
    assert_no_exception(page)
    expect(page.locator('[data-testid="stSidebar"]')).to_be_hidden(timeout=T)
    size = page.evaluate("getComputedStyle(document.documentElement).fontSize")
    assert size == "22px"
    page.screenshot(path=str(artifacts_dir / f"present-{path.lower() or 'home'}.png"))


def test_presentation_mode_moves_chart_by_chart(page: Page):
    page.goto(f"/Compare?present=1&{SMALL}&seed=42&go=1")
    wait_complete(page)
    charts = page.locator(CHART)
    expect(charts).to_have_count(4, timeout=T)
    assert page.get_by_role("button", name="SVG").count() == 0  # no export chrome
    tops = lambda: page.evaluate(  # noqa: E731
        "Array.from(document.querySelectorAll('[data-testid=\"stPlotlyChart\"]'))"
        ".map(e => Math.round(e.getBoundingClientRect().top))"
    )
    page.wait_for_function(
        "document.querySelectorAll('[data-testid=\"stPlotlyChart\"] .main-svg').length >= 4", timeout=T
    )
    settle(page)
    page.locator("h1").first.click()  # focus the page, not a widget
    for i in (0, 1, 2, 3):
        page.keyboard.press("n")
        page.wait_for_function(
            f"Math.abs(document.querySelectorAll('[data-testid=\"stPlotlyChart\"]')[{i}]"
            ".getBoundingClientRect().top) < 20",
            timeout=T,
        )
    page.keyboard.press("p")
    page.wait_for_function(
        "Math.abs(document.querySelectorAll('[data-testid=\"stPlotlyChart\"]')[2]"
        ".getBoundingClientRect().top) < 20",
        timeout=T,
    )
    heights = page.evaluate(
        "Array.from(document.querySelectorAll('[data-testid=\"stPlotlyChart\"]'))"
        ".map(e => e.getBoundingClientRect().height)"
    )
    assert min(heights) >= 650, (heights, tops())
    # the page links keep presentation mode
    page.goto("/?present=1")
    settle(page)
    href = (
        page.locator('[data-testid="stPageLink"] a').filter(has_text="Compare filters").get_attribute("href")
    )
    assert "present=1" in href


def test_settings_carry_from_compare_to_noise(page: Page):
    page.goto("/Compare?seed=42&runs=33&out=isolated&flt=kf&flt=sage-husa")
    settle(page)
    expect_value(page, "Seed", "42")
    seed = page.get_by_label("Seed", exact=True)
    seed.fill("43")  # a change made on the page, not only the link
    seed.press("Enter")
    page.wait_for_url(re.compile(r"seed=43"), timeout=T)
    settle(page)
    page.locator('[data-testid="stSidebar"] [data-testid="stPageLink"]').filter(has_text="Noise").click()
    expect(page.locator("h1").first).to_have_text("Noise: R̂ inspection", timeout=T)
    settle(page)
    assert_no_exception(page)
    expect_value(page, "Seed", "43")
    expect_value(page, "Monte Carlo runs", "33")
    assert "out=isolated" in page.url and "seed=43" in page.url
    ms = page.locator('[data-testid="stMultiSelect"]').first
    expect(ms).to_contain_text("sage-husa")
    expect(ms).not_to_contain_text("oracle-kf")
    expect(page.get_by_text("Outlier model")).to_be_visible()
    # the Compare link opened on /Noise is the same experiment (the pages share their defaults)
    page.goto("/Noise?seed=42")
    settle(page)
    from navlab.ui.widgets import PageDefaults

    want = PageDefaults().outliers
    expect(page.get_by_role("combobox", name="Outlier model")).to_have_value(want, timeout=T)


def _address_matches_the_widgets(page: Page) -> None:
    """The experiment widgets show what the address holds (its value, else the page default);
    polled, as the page may still be writing the address."""
    from urllib.parse import parse_qs, urlparse

    from navlab.ui.widgets import default_spec

    d = default_spec()
    runs = page.get_by_label("Monte Carlo runs", exact=True)
    noise = page.get_by_role("combobox", name="Noise schedule (true R(t))")
    seen = None
    for _ in range(60):
        q = parse_qs(urlparse(page.url).query)
        want = (q.get("runs", [str(d.runs)])[-1], q.get("noise", [d.noise_schedule])[-1])
        seen = (page.url, want, (runs.input_value(), noise.input_value()))
        if seen[1] == seen[2]:
            return
        page.wait_for_timeout(500)
    raise AssertionError(f"the address and the widgets disagree: {seen}")


def test_browser_back_to_compare_shows_the_experiment_of_its_address(page: Page):
    """Compare (a link's experiment) → Sweep by the page menu, then Back until Compare: every run
    page reached by Back shows the experiment its address holds. Streamlit drops the parameters
    of the page left and resets URL-bound widgets on a history step, so Compare showed the
    defaults under an address holding runs=33&noise=ramp. (Which addresses Back passes through
    is Streamlit's: a page change can add an address without parameters.)
    """
    page.goto("/Compare?runs=33&noise=ramp")
    settle(page)
    page.locator('[data-testid="stSidebar"] [data-testid="stPageLink"]').filter(
        has_text="Sweep"
    ).first.click()
    expect(page.locator("h1").first).to_have_text("Sweep a parameter", timeout=T)
    settle(page)
    expect_value(page, "Monte Carlo runs", "33")  # the link carried it
    for _ in range(4):  # Streamlit may push an extra address of the page on the way
        page.go_back()
        settle(page)
        assert_no_exception(page)
        _address_matches_the_widgets(page)
        if page.locator("h1").first.inner_text() == "Compare filters":
            break
    expect(page.locator("h1").first).to_have_text("Compare filters", timeout=T)


def _download(page: Page, label: str, nth: int = 0) -> Path:
    with page.expect_download(timeout=T) as d:
        page.get_by_role("button", name=label, exact=True).nth(nth).click()
    return Path(d.value.path())


def test_downloads_parse_and_the_notebook_reproduces_the_rmse(page: Page, tmp_path: Path, monkeypatch):
    """Every download of one Compare run: the configuration, the metrics and RMSE-per-epoch CSVs,
    the paper table (LaTeX, Markdown), the SVG (a publication figure, text kept as text) and PNG
    figure, the script, and the notebook, executed, reproducing the run's RMSE."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    page.goto(f"/Compare?{SMALL}&seed=3&go=1")
    wait_complete(page)
    spec = ExperimentSpec.from_json(_download(page, "Configuration (JSON)").read_text())
    assert spec.runs == 8 and spec.seed == 3 and spec.scenario_params == {"epochs": 40}
    assert spec.filters == ("kf", "oracle-kf", "chi2-kf")
    metrics = pd.read_csv(_download(page, "Metrics (CSV)"))
    assert {"filter", "metric", "value", "unit"} <= set(metrics.columns)
    assert set(metrics["filter"]) == {"kf", "oracle-kf", "chi2-kf", "pcrb"}  # and the floor's rows
    assert (metrics[metrics.metric == "runs"].value == 8).all()
    tex = _download(page, "Table (LaTeX)").read_text()  # the headline table for a paper
    assert "\\toprule" in tex and "8 Monte Carlo runs (seed 3" in tex and tex.isascii()
    assert _download(page, "Table (Markdown)").read_text().startswith("Table: ")
    curves = pd.read_csv(_download(page, "RMSE per epoch (CSV)"))
    assert {"filter", "group", "epoch", "rmse"} <= set(curves.columns)
    assert curves.epoch.max() == 40
    svg = _download(page, "SVG").read_text()
    assert ET.fromstring(svg).tag.endswith("svg")
    assert "Position error over time" in svg and "KF" in svg  # text kept as text
    png = _download(page, "PNG").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    nb_path = _download(page, "Notebook (.ipynb)")
    script = _download(page, "Script (.py)").read_text()
    assert "run_experiment(SPEC)" in script
    nb = nbformat.read(nb_path, as_version=4)
    # the kernel runs in a temp folder (the notebook writes its figures there) and imports this
    # checkout's navlab, installed or not
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    nbclient.NotebookClient(nb, timeout=600, resources={"metadata": {"path": str(tmp_path)}}).execute()
    out = "".join(o.get("text", "") for o in nb.cells[-1].outputs)
    got = json.loads(out.strip().splitlines()[-1])
    want = metrics[metrics.metric == "rmse_pos"].set_index("filter")["value"]
    assert set(want.index) == {"kf", "oracle-kf", "chi2-kf"}
    for key, v in want.items():
        assert got[f"{key}|rmse_pos"] == pytest.approx(v, rel=1e-9), key
    assert any(o.get("data", {}).get("image/svg+xml") for c in nb.cells for o in c.get("outputs", []))
