"""Dashboard timings (issue 6 targets): server compute per run, and Run → first chart in a browser.

    python benchmarks/app_timing.py              # server-side timings only
    python benchmarks/app_timing.py --browser    # + headless Chromium against a fresh server

Server side: a compare run on cv2d (100 epochs, 100 runs) with every linear filter (the KF-update
filters of the HAKF and IRAKF papers with their baselines), with every registered filter, and with
the page's default three; timed one-shot (``run_experiment``) and as the Compare page runs it
(``navlab.ui.runner.iter_chunks``): the first time in a process the chunking follows a cost prior,
again the costs learned from the first (one batch when short or overhead-bound, else a tenth of
the runs first); and sins-gps (850 epochs, 50 runs, 4 filters).
Browser: Run → first results chart drawn (a Plotly legend visible), on a freshly started server
(cold) and again (warm). Not a test: numbers depend on the machine's load (printed first).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def server_timings(repeat: int) -> None:
    from navlab import tables
    from navlab.diagnostics import explain
    from navlab.experiment import ExperimentSpec, run_experiment
    from navlab.filters import registry
    from navlab.scenarios import scenario_registry
    from navlab.ui import runner
    from navlab.ui.runner import iter_chunks

    reg = registry()
    # the linear Kalman filters: KF-update filters of the HAKF and IRAKF papers and their baselines
    kf_modules = ("navlab.filters.kalman", "navlab.filters.huber_vb", "navlab.filters.sage_husa")
    linear = tuple(k for k, c in reg.items() if c.__module__.startswith(kf_modules))
    every = tuple(reg)
    cases = [
        ("cv2d, 100 runs, every linear (KF-update) filter", ExperimentSpec(filters=linear, runs=100)),
        (
            "cv2d, 100 runs, every registered filter (EKF/UKF/VB-EKF/WLS too)",
            ExperimentSpec(filters=every, runs=100),
        ),
        ("cv2d, 100 runs, kf/oracle-kf/chi2-kf (the page's default)", ExperimentSpec(runs=100)),
    ]
    if "sins-gps" in scenario_registry():
        sg = scenario_registry()["sins-gps"]
        cases.append(
            (
                "sins-gps, 50 runs, its 4 default filters",
                ExperimentSpec(scenario="sins-gps", filters=tuple(sg.default_filters)[:4], runs=50),
            )
        )

    def paged(spec: ExperimentSpec) -> float:
        t = time.perf_counter()
        for _r in iter_chunks(spec):
            pass
        return time.perf_counter() - t

    def statistics(res) -> float:
        """The page's table: every headline interval and the paired test against the KF."""
        t = time.perf_counter()
        tables.headline(res, compare_to="kf" if "kf" in res.runs else None, explanations=False)
        explain(res)
        return time.perf_counter() - t

    for name, spec in cases:
        print(f"\n{name}: filters {', '.join(spec.filters)}")
        for i in range(repeat):
            t = time.perf_counter()
            res = run_experiment(spec)
            one = time.perf_counter() - t
            stat = statistics(res)
            runner._COST.clear()  # the page's first run of these filters: the cost prior decides
            cold = paged(spec)
            warm = paged(spec)  # again: the costs learned decide
            print(
                f"  [{i}] one-shot {one:6.2f} s + intervals, paired tests and explanations "
                f"{stat:5.2f} s = {one + stat:5.2f} s   as the page runs it: first time "
                f"{cold:6.2f} s, again {warm:6.2f} s (+ the same statistics)"
            )


def browser_timings(repeat: int) -> None:
    sys.path.insert(0, str(ROOT / "tests" / "e2e"))
    from conftest import CHROMIUM_ARGS, serve
    from playwright.sync_api import expect, sync_playwright

    T = 180_000
    log = Path(os.environ.get("TMPDIR", "/tmp")) / "navlab-app-timing.log"
    with serve(log) as url, sync_playwright() as p:
        b = p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
        page = b.new_page(viewport={"width": 1400, "height": 1000})
        for i in range(repeat):
            page.goto(f"{url}/Compare?seed={1000 + i}")
            expect(page.locator("h1").first).to_be_visible(timeout=T)
            expect(page.locator('[data-testid="stStatusWidget"]')).to_have_count(0, timeout=T)
            time.sleep(2)  # a user reads the page before pressing Run
            t0 = time.monotonic()
            page.get_by_role("button", name="Run", exact=True).click()
            expect(page.locator('[data-testid="stPlotlyChart"] .legendtext').first).to_be_visible(timeout=T)
            first = time.monotonic() - t0
            expect(page.get_by_text(re.compile(r"runs \(complete\)"))).to_be_visible(timeout=T)
            done = time.monotonic() - t0
            cap = page.get_by_text(re.compile(r"done: \d+ runs")).inner_text()
            kind = "cold (fresh server)" if i == 0 else "warm"
            print(f"  [{i}] {kind}: Run → first chart {first:5.2f} s, → complete {done:5.2f} s ({cap})")
        b.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--browser", action="store_true", help="also time Run → first chart")
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args()
    print(f"load average {os.getloadavg()} on {os.cpu_count()} CPUs")
    server_timings(a.repeat)
    if a.browser:
        print("\nbrowser: default Compare run (cv2d, 100 runs, kf/oracle-kf/chi2-kf)")
        browser_timings(a.repeat + 1)


if __name__ == "__main__":
    main()
