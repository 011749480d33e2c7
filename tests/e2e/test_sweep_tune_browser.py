"""Sweep and Tune in a real browser, on the server's default executor (this machine: these small
jobs run in the server process, and the page says so).

A unique seed per test run makes every task new, so the cluster really computes (a repeated
configuration would come from the results store).
"""

from __future__ import annotations

import random
import re

from playwright.sync_api import Page, expect

T = 180_000  # ms: a shared 2-core machine
CHART = '[data-testid="stPlotlyChart"]'
SEED = random.SystemRandom().randrange(10**6, 2**31 - 1)


def _button(page: Page, name: str):
    return page.get_by_role("button", name=name, exact=True).and_(page.locator("button:not([kind=header])"))


def _settle(page: Page) -> None:
    expect(page.locator("h1").first).to_be_visible(timeout=T)
    expect(page.locator('[data-testid="stStatusWidget"]')).to_have_count(0, timeout=T)


def _clean(page: Page) -> None:
    expect(page.locator('[data-testid="stException"]')).to_have_count(0)
    expect(page.get_by_text("could not start the embedded Dask cluster")).to_have_count(0)


def test_sweep_on_the_embedded_cluster_stop_and_resume(page: Page):
    q = f"runs=100&sc.cv2d.epochs=300&flt=kf&flt=chi2-kf&flt=huber-kf&swn=6&out=mixture&seed={SEED}"
    page.goto(f"/Sweep?{q}")
    _settle(page)
    expect(page.get_by_text("embedded Dask cluster").first).to_be_visible(timeout=T)
    _button(page, "Run sweep").click()
    expect(page.get_by_text(re.compile(r"\b[1-9]\d*/18 tasks"))).to_be_visible(timeout=T)
    _button(page, "Stop").click()
    _settle(page)
    _clean(page)
    resumed = page.get_by_text(re.compile(r"tasks (finished and )?kept.*press Run sweep to resume"))
    done = page.get_by_text(re.compile(r"6 points ·"))
    expect(resumed.or_(done)).to_be_visible(timeout=T)
    _button(page, "Run sweep").click()
    expect(page.get_by_text(re.compile(r"6 points · [1-9]\d* of 18 tasks from the store"))).to_be_visible(
        timeout=T
    )
    _settle(page)
    _clean(page)
    expect(page.locator(CHART)).to_have_count(2, timeout=T)
    expect(page.locator(CHART).first.get_by_text("outlier ratio α").first).to_be_visible()


def test_two_d_sweep_in_the_browser(page: Page):
    q = "runs=8&sc.cv2d.epochs=40&flt=kf&flt=huber-kf&swn=3&sw2=true&sw2n=2&swp2=fp.huber-kf.gamma"
    q += f"&seed={SEED}"
    page.goto(f"/Sweep?{q}")
    _settle(page)
    _button(page, "Run sweep").click()
    expect(page.locator(f"{CHART} .heatmaplayer")).to_have_count(1, timeout=T)
    _settle(page)
    _clean(page)
    # where the tasks ran, and why
    expect(page.get_by_text(re.compile(r"Done: \d+ tasks in this process in .* s \(below"))).to_be_visible()


def test_tune_then_open_compare_with_the_tuned_parameters(page: Page):
    q = f"runs=10&sc.cv2d.epochs=30&flt=kf&flt=huber-kf&tn_budget=4&tn_train_runs=4&seed={SEED}"
    page.goto(f"/Tune?{q}")
    _settle(page)
    _button(page, "Run tuning").click()
    expect(page.get_by_text("Default against tuned, on the test seeds")).to_be_visible(timeout=T)
    _settle(page)
    _clean(page)
    expect(page.locator(CHART)).to_have_count(1, timeout=T)  # the Huber KF's landscape
    # every button shows its whole label (in narrow columns they read "P…", "Tuned configuration (JS…")
    cut = page.evaluate(
        """() => Array.from(document.querySelectorAll('[data-testid="stMain"] button'))
        .filter(b => b.offsetWidth > 0)
        .filter(b => Array.from(b.querySelectorAll('*')).some(e => e.scrollWidth > e.clientWidth + 1))
        .map(b => b.innerText)"""
    )
    assert cut == [], cut
    _button(page, "Open Compare with the tuned parameters").click()
    expect(page.locator("h1").first).to_have_text(re.compile("Compare filters"), timeout=T)
    _settle(page)
    expect(page).to_have_url(re.compile(rf"/Compare\?.*seed={SEED}"), timeout=T)
    assert "flt=huber-kf" in page.url
