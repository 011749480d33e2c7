"""The Reproduce page in a real browser (issue 21 item 3), on a server with its own empty results
store: the default answers with verdict rows as seed blocks finish and fits 1440×900; Stop keeps
the finished seed blocks and Run resumes; closing the browser stops the work, worker processes
included, and the abandoned reproduction resumes from the store.
"""

from __future__ import annotations

import contextlib
import os
import re
import time
from collections.abc import Iterator
from pathlib import Path

import psutil
import pytest
from conftest import log_name, serve
from playwright.sync_api import Browser, Page, expect

from navlab.reproduce import REPRODUCTIONS

T = 90_000
VIEWPORT = {"width": 1440, "height": 900}
# the verdicts a run gives ("not testable" rows are listed before any run)
VERDICT = re.compile(r"^(reproduced|contradicted|inconclusive|setup-dependent)$")
# long enough to run in worker processes and to be still computing seconds after the first verdict
LONG = "rep=irakf&rep_seeds=16&rep_seed=7"  # a base seed of its own: nothing of it in the store
# seed blocks 0, 1, 2–3, 4–7, 8–15: Stop pressed at the first provisional verdict lands before the
# last block (eight seeds, as many as all before it) is done, and Run then computes only what is
# left. With 8 seeds (last block four) the blocks, computed in worker processes, sometimes all
# finished before a loaded machine's page showed the first verdict and the Stop landed.
STOPPED = 16


@pytest.fixture(scope="module")
def server(artifacts_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    """(URL, results store folder) of a server of its own with an empty store."""
    store = tmp_path_factory.mktemp("store")
    saved = os.environ.get("NAVLAB_STORE")
    os.environ["NAVLAB_STORE"] = str(store)
    try:
        with serve(artifacts_dir / log_name("streamlit-server-reproduce")) as url:
            yield url, store
    finally:
        if saved is None:
            os.environ.pop("NAVLAB_STORE", None)
        else:
            os.environ["NAVLAB_STORE"] = saved


def _workers(url: str) -> list[psutil.Process]:
    """The server's worker processes (multiprocessing's, not its resource tracker)."""
    port = url.rsplit(":", 1)[1]
    for p in psutil.process_iter(["cmdline"]):
        if f"--server.port={port}" in " ".join(p.info["cmdline"] or []):
            kids = []
            for c in p.children(recursive=True):
                with contextlib.suppress(psutil.NoSuchProcess):
                    if c.status() != psutil.STATUS_ZOMBIE and "spawn_main" in " ".join(c.cmdline()):
                        kids.append(c)
            return kids
    raise AssertionError(f"no server on port {port}")


def _idle_within(url: str, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if not _workers(url):
            return True
        time.sleep(0.5)
    return False


def _open(page: Page, url: str, query: str = "") -> Page:
    """``page`` (the reused tab, tests/e2e/conftest.py) on this server's Reproduce page."""
    page.set_viewport_size(VIEWPORT)
    page.goto(f"{url}/Reproduce" + (f"?{query}" if query else ""))
    expect(page.locator("h1").first).to_be_visible(timeout=T)
    expect(page.locator('[data-testid="stStatusWidget"]')).to_have_count(0, timeout=T)
    return page


def _button(page: Page, name: str):
    return page.get_by_role("button", name=name, exact=True).and_(page.locator("button:not([kind=header])"))


def _verdicts(page: Page):
    return page.locator('[data-testid="stTable"] td').filter(has_text=VERDICT)


def test_default_answers_in_seconds_and_fits_the_screen(page: Page, server, artifacts_dir: Path):
    url, _ = server
    _open(page, url)
    expect(page.get_by_text("--seeds 20")).to_be_visible()  # the CLI line of the full judgement
    expect(page.get_by_text("not judged yet").first).to_be_visible()
    _button(page, "Run").click()
    expect(_verdicts(page).first).to_be_visible(timeout=T)
    expect(page.get_by_text(re.compile(r"^Judged on 5 seeds"))).to_be_visible(timeout=T)
    r = REPRODUCTIONS["irakf"]
    runs = 5 * r.default_runs * len(r.experiments)  # 5 seeds of every experiment
    expect(page.get_by_text(re.compile(rf"^{runs}/{runs} runs"))).to_be_visible()  # progress ends at 100 %
    charts = 2 + len(r.experiments) * len(r.curves)  # the claims, the evidence, one per curve
    expect(page.locator('[data-testid="stPlotlyChart"]')).to_have_count(charts, timeout=T)
    expect(_button(page, "Stop")).to_have_count(0)  # nothing to stop any more
    expect(page.locator('[data-testid="stException"]')).to_have_count(0)
    # every table fits its container (no sideways scrolling for the verdict); no None/NaN cell
    overflow = page.evaluate(
        """() => Array.from(document.querySelectorAll('[data-testid="stTable"]'))
             .map(t => t.scrollWidth - t.clientWidth)"""
    )
    assert overflow and max(overflow) <= 1, overflow
    cells = page.locator('[data-testid="stTable"] td').all_inner_texts()
    assert len(cells) >= 15 * 7 and not [c for c in cells if c.strip() in ("None", "nan", "NaN")]
    page.screenshot(path=str(artifacts_dir / "reproduce-default-1440.png"))
    page.set_viewport_size({"width": 1440, "height": 4200})  # the whole page for a human to read
    page.screenshot(path=str(artifacts_dir / "reproduce-default-1440-full.png"))
    # presentation mode: the judged reproduction is shown (from the server), without downloads
    _open(page, url, "present=1")
    expect(_verdicts(page).first).to_be_visible()
    expect(page.locator('[data-testid="stPlotlyChart"]')).to_have_count(charts, timeout=T)
    expect(page.locator('[data-testid="stDownloadButton"]')).to_have_count(0)


def test_stop_keeps_the_seed_blocks_and_run_resumes(page: Page, server):
    url, _ = server
    _open(page, url, f"rep=irakf&rep_seeds={STOPPED}&rep_seed=3")
    _button(page, "Run").click()
    provisional = re.compile(rf"^Provisional: judged on \d+ seeds? of {STOPPED}")
    expect(page.get_by_text(provisional)).to_be_visible(timeout=T)
    stop = _button(page, "Stop")
    assert abs(stop.bounding_box()["y"] - _button(page, "Run").bounding_box()["y"]) < 20  # beside Run
    stop.click()
    kept = page.get_by_text(re.compile(rf"^\d+ of {STOPPED} seeds judged and kept"))
    expect(kept).to_be_visible(timeout=T)
    done = int(kept.inner_text().split()[0])
    assert 1 <= done < STOPPED
    assert _idle_within(url, 30)  # Stop ended the work, worker processes included
    _button(page, "Run").click()  # resumes: the kept seeds' verdicts come at once
    expect(page.get_by_text(re.compile(rf"^Judged on {STOPPED} seeds"))).to_be_visible(timeout=3 * T)
    expect(page.locator('[data-testid="stException"]')).to_have_count(0)


def test_closing_the_browser_stops_the_work_and_it_resumes(browser: Browser, page: Page, server):
    url, store = server
    context = browser.new_context(viewport=VIEWPORT)  # its own, to close mid-run
    closing = context.new_page()
    closing.goto(f"{url}/Reproduce?{LONG}")
    expect(closing.locator('[data-testid="stStatusWidget"]')).to_have_count(0, timeout=T)
    before = len(list(store.glob("??/*.npz")))  # the other tests' blocks
    _button(closing, "Run").click()
    expect(_verdicts(closing).first).to_be_visible(timeout=T)
    assert _workers(url)  # seeds 1–15 compute in worker processes
    context.close()  # the browser goes away mid-run
    assert _idle_within(url, 30), [p.cmdline() for p in _workers(url)]
    kept = len(list(store.glob("??/*.npz"))) - before
    _open(page, url, LONG)  # the abandoned reproduction: its finished seeds are shown
    expect(page.get_by_text(re.compile(r"^\d+ of 16 seeds judged and kept"))).to_be_visible(timeout=T)
    expect(_verdicts(page).first).to_be_visible()
    n = len(REPRODUCTIONS["irakf"].experiments)  # one stored block per experiment and seed range
    assert n <= kept < n * 5  # seed 0 of every experiment at least; not all 5 seed ranges
