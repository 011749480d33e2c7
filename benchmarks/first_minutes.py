"""The first five minutes (issue 21), measured as a user meets them, side by side in one run.

    python benchmarks/first_minutes.py [--repeat 3] [--only sweep|reproduce]

* **Reproduce**: the page's default (the fastest paper at a few seeds), click Run → first verdict
  row (target ≤ 10 s on this 2-core machine), and → every seed judged.
* **Sweep**: the page's default, click **Run sweep** → first chart, on the app's default
  executor (``NAVLAB_DASK_SCHEDULER`` unset: this machine, as a user gets it) against
  ``NAVLAB_DASK_SCHEDULER=serial``, in pairs whose order alternates so both see the same load;
  their ratio of medians and of minima (target ≤ 1.0) and where the default executor ran the
  tasks and why (the page's own words).

Every measurement starts a fresh ``streamlit run app.py`` on a free loopback port
(tests/e2e/conftest.py's ``serve``) with an empty results store, and drives Debian's Chromium
(Playwright) at 1440×900. Not a test: the figures move with the machine's load, printed beside
them; read min and median.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "e2e")]  # navlab; conftest's serve() and Chromium

T_MS = 600_000  # fail-safe limit of every browser wait
CHART = '[data-testid="stPlotlyChart"]'
MODES = {"default": None, "serial": "serial"}  # NAVLAB_DASK_SCHEDULER of each measurement
VIEWPORT = {"width": 1440, "height": 900}
TARGET_S = 10.0
# a verdict in the verdict table (before Run the table lists the claims as "not judged yet")
VERDICT = re.compile(r"^(reproduced|contradicted|inconclusive)$")


def measure_reproduce(repeats: int = 3, timeout_s: float = 300.0) -> dict:
    """Click Run → first verdict row (and → every seed judged) on the Reproduce page's defaults,
    each repeat on a fresh server with an empty results store.

    Returns ``{"what", "first_row_s", "all_seeds_s", "load", "first_row_min_s",
    "first_row_median_s", "target_s"}`` (lists per repeat; ``load``: the 1-minute load average
    at each click).
    """
    from conftest import CHROMIUM, CHROMIUM_ARGS, serve  # the e2e suite's server and browser
    from playwright.sync_api import expect, sync_playwright

    from navlab.reproduce import REPRODUCTIONS
    from navlab.ui.reproduce import APP_SEEDS, default_key

    key = default_key(sorted(REPRODUCTIONS))
    what = f"{key}, {APP_SEEDS} seeds × {REPRODUCTIONS[key].default_runs} runs (the page's defaults)"
    T = timeout_s * 1000
    first, every, load = [], [], []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            for i in range(repeats):
                with (
                    tempfile.TemporaryDirectory(prefix="navlab-bench-store-") as store,
                    mock.patch.dict(os.environ, NAVLAB_STORE=store),
                    serve(Path(tempfile.gettempdir()) / f"navlab-bench-reproduce-{i}.log") as url,
                ):
                    page = browser.new_page(viewport=VIEWPORT)
                    page.goto(f"{url}/Reproduce")
                    expect(page.get_by_text("Press Run to judge")).to_be_visible(timeout=T)
                    expect(page.locator('[data-testid="stStatusWidget"]')).to_have_count(0, timeout=T)
                    run = page.get_by_role("button", name="Run", exact=True)
                    load.append(os.getloadavg()[0])
                    t0 = time.monotonic()
                    run.click()
                    verdict = page.locator('[data-testid="stTable"] td').filter(has_text=VERDICT)
                    expect(verdict.first).to_be_visible(timeout=T)
                    first.append(time.monotonic() - t0)
                    expect(page.get_by_text(re.compile(r"Judged on \d+ seeds"))).to_be_visible(timeout=T)
                    every.append(time.monotonic() - t0)
                    page.close()
        finally:
            browser.close()
    return {
        "what": what,
        "first_row_s": first,
        "all_seeds_s": every,
        "load": load,
        "first_row_min_s": min(first),
        "first_row_median_s": statistics.median(first),
        "target_s": TARGET_S,
    }


def _click_to_chart(browser, scheduler: str | None) -> tuple[float, str]:
    """(seconds from the click on Run sweep to the first chart, the page's 'Done: …' line) on a
    fresh server with an empty store and NAVLAB_DASK_SCHEDULER=``scheduler`` (None: empty, the
    default).
    """
    from conftest import serve
    from playwright.sync_api import expect

    tmp = tempfile.TemporaryDirectory(prefix="navlab-bench-")
    env = {"NAVLAB_STORE": str(Path(tmp.name) / "store"), "NAVLAB_DASK_SCHEDULER": scheduler or ""}
    with tmp, mock.patch.dict(os.environ, env), serve(Path(tmp.name) / "server.log") as url:
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        try:
            page.goto(f"{url}/Sweep", timeout=T_MS)
            run = page.get_by_role("button", name="Run sweep", exact=True)
            expect(run).to_be_enabled(timeout=T_MS)
            expect(page.locator('[data-testid="stStatusWidget"]')).to_have_count(0, timeout=T_MS)
            t0 = time.monotonic()
            run.click()
            expect(page.locator(CHART).first).to_be_visible(timeout=T_MS)
            seconds = time.monotonic() - t0
            done = page.get_by_text("Done:", exact=False)
            report = done.first.inner_text() if done.count() else "(no report on the page)"
        finally:
            page.close()
    return seconds, " ".join(report.split())


def measure_sweep(repeat: int = 1) -> dict:
    """Click → first chart of the Sweep page's default, on the default executor and serially,
    each on a fresh server, ``repeat`` times alternately. Returns ``{"default": [seconds…],
    "serial": [seconds…], "ratio": median default / median serial, "ratio_min": the same of the
    minima, "report": where the default
    executor ran the tasks and why (the page's words), "load": the load average before}``.
    """
    from conftest import CHROMIUM, CHROMIUM_ARGS
    from playwright.sync_api import sync_playwright

    out: dict = {"default": [], "serial": [], "load": os.getloadavg(), "report": ""}
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            for i in range(repeat):  # pairs in turn: default first, then serial first, …
                for mode, scheduler in list(MODES.items())[:: 1 if i % 2 == 0 else -1]:
                    seconds, report = _click_to_chart(browser, scheduler)
                    out[mode].append(seconds)
                    if mode == "default":
                        out["report"] = report
        finally:
            browser.close()
    out["ratio"] = statistics.median(out["default"]) / statistics.median(out["serial"])
    out["ratio_min"] = min(out["default"]) / min(out["serial"])
    return out


def _line(xs: list[float]) -> str:
    runs = ", ".join(f"{x:.1f}" for x in xs)
    return f"median {statistics.median(xs):5.1f} s, min {min(xs):5.1f} s   (runs: {runs})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="measurements of each (sweep: alternately)")
    ap.add_argument("--only", choices=("sweep", "reproduce"))
    a = ap.parse_args()
    load = " ".join(f"{v:.2f}" for v in os.getloadavg())
    print(f"{os.cpu_count()} CPUs; load average {load}; fresh server and empty store per measurement")
    if a.only != "sweep":
        r = measure_reproduce(a.repeat)
        print(f"Reproduce page, {r['what']}: click Run →")
        for i, (f, e, ld) in enumerate(zip(r["first_row_s"], r["all_seeds_s"], r["load"], strict=True)):
            print(f"  [{i}] first verdict row {f:5.2f} s, all seeds judged {e:5.2f} s  (load {ld:.2f})")
        ok = "meets" if r["first_row_median_s"] <= r["target_s"] else "MISSES"
        print(
            f"  first verdict row: min {r['first_row_min_s']:.2f} s, median {r['first_row_median_s']:.2f} s"
            f"  ({ok} the target ≤ {r['target_s']:.0f} s)"
        )
    if a.only != "reproduce":
        s = measure_sweep(a.repeat)
        print("Sweep page at its defaults, click Run sweep → first chart:")
        print(f"  default executor  {_line(s['default'])}")
        print(f"  serial            {_line(s['serial'])}")
        ok = "meets" if s["ratio"] <= 1.0 else "MISSES"
        print(
            f"  ratio default / serial: medians {s['ratio']:.2f}, minima {s['ratio_min']:.2f}"
            f"  ({ok} the target ≤ 1.0 on the medians)"
        )
        print(f"  the page: {s['report']}")


if __name__ == "__main__":
    main()
