"""A default Sweep from click to first chart, on the app's default executor against serial.

    python benchmarks/first_minutes_sweep.py [--repeat 3]

Each measurement starts a fresh ``streamlit run app.py`` on a free loopback port with an empty
results store (nothing comes from a cache), opens the Sweep page at its defaults in Debian's
Chromium (Playwright, 1440×900), clicks **Run sweep** and times click → first chart visible:
once with the app's default executor (``NAVLAB_DASK_SCHEDULER`` unset: this machine, as a user
gets it) and once with ``NAVLAB_DASK_SCHEDULER=serial``, in pairs whose order alternates, so
both see the same load. It prints both, their ratio of medians and of minima (target ≤ 1.0)
and where the default executor ran the tasks and why (the page's own words). The load average
is printed too: on a shared machine the times move with it.

:func:`measure_sweep` returns the figures (for a combined first-minutes benchmark).
"""

from __future__ import annotations

import argparse
import os
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
    ap.add_argument("--repeat", type=int, default=3, help="measurements of each (alternately)")
    a = ap.parse_args()
    r = measure_sweep(a.repeat)
    load = " ".join(f"{x:.1f}" for x in r["load"])
    print("Sweep page at its defaults, click Run sweep → first chart (fresh server and store each)")
    print(f"  default executor  {_line(r['default'])}")
    print(f"  serial            {_line(r['serial'])}")
    print(f"  ratio default / serial: medians {r['ratio']:.2f}, minima {r['ratio_min']:.2f}  (target ≤ 1.0)")
    print(f"  the page: {r['report']}")
    print(f"  load average before: {load} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
