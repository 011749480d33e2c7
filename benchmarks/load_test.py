"""Load test: N browser sessions each running a Compare at once against one server (loopback only).

    python benchmarks/load_test.py                   # 20 sessions, 100 runs each
    python benchmarks/load_test.py --sessions 5 --runs 30

Checks and prints: every session finishes (within --timeout), no cross-talk (each session's table
shows exactly the numbers the library computes for that session's seed), and the server's memory
(resident set of the streamlit process and its children: before, peak while running, and after the
sessions closed: 20 s later, while the result store still holds the finished runs, and after
--settle seconds, by when Streamlit has dropped the closed sessions (server.disconnectedSessionTTL,
120 s) and the store's sweep the results nobody used for --ttl seconds (NAVLAB_RESULT_TTL, given to
the server; the deployment default is 900 s). Bounded in count and time; not a test (the figures
depend on the machine's load, printed first). Uses Debian's /usr/bin/chromium.
"""

from __future__ import annotations

import argparse
import os
import re
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CHROMIUM = "/usr/bin/chromium"
ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rss_bytes(pid: int) -> int:
    """Resident memory of a process and its children (from /proc)."""
    total = 0
    pids = [pid]
    try:
        out = subprocess.run(["ps", "--ppid", str(pid), "-o", "pid="], capture_output=True, text=True)
        pids += [int(p) for p in out.stdout.split()]
    except (OSError, ValueError):
        pass
    for p in pids:
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1]) * 1024
        except OSError:
            continue
    return total


class Sampler(threading.Thread):
    def __init__(self, pid: int) -> None:
        super().__init__(daemon=True)
        self.pid, self.peak, self.stop = pid, 0, threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            self.peak = max(self.peak, rss_bytes(self.pid))
            time.sleep(0.2)


def expected(seed: int, runs: int) -> float:
    """The KF's position RMSE of the Compare page's default run with this seed, from the library."""
    from navlab.experiment import ExperimentSpec, run_experiment
    from navlab.metrics import summarize

    df = summarize(run_experiment(ExperimentSpec(runs=runs, seed=seed)), metrics=[])
    return float(df[(df["filter"] == "kf") & (df.metric == "rmse_pos")].value.iloc[0])


def stored_bytes(runs: int) -> int:
    """What one finished Compare leaves in the server's result store (a bounded LRU, 768 MB)."""
    from navlab.experiment import ExperimentSpec, run_experiment
    from navlab.ui.runner import results_nbytes

    return results_nbytes(run_experiment(ExperimentSpec(runs=runs)))


def downloaded(page) -> float:
    """The same number from the session's own 'Metrics (CSV)' download."""
    import io

    import pandas as pd

    with page.expect_download() as d:
        page.get_by_role("button", name="Metrics (CSV)").click()
    df = pd.read_csv(io.StringIO(Path(d.value.path()).read_text()))
    return float(df[(df["filter"] == "kf") & (df.metric == "rmse_pos")].value.iloc[0])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sessions", type=int, default=20)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds for every session to finish")
    ap.add_argument("--ttl", type=float, default=30.0, help="the server's NAVLAB_RESULT_TTL (seconds)")
    ap.add_argument(
        "--settle",
        type=float,
        default=180.0,
        help="seconds after the sessions closed for the last reading (≥ 120 s + the TTL's sweep)",
    )
    a = ap.parse_args()
    if not 1 <= a.sessions <= 40:
        ap.error("--sessions must be between 1 and 40")
    from playwright.sync_api import expect, sync_playwright

    print(f"load: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; {a.sessions} sessions × {a.runs} runs")
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    log = open(Path(os.environ.get("TMPDIR", "/tmp")) / "navlab-load-test.log", "w")  # noqa: SIM115 (closed below)
    server = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "streamlit",
            "run",
            "app.py",
            "--server.address=127.0.0.1",
            f"--server.port={port}",
            "--server.headless=true",
            "--browser.gatherUsageStats=false",
            "--server.fileWatcherType=none",
        ],
        cwd=ROOT,
        env={**os.environ, "NAVLAB_RESULT_TTL": str(a.ttl)},
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
    )
    ok = False
    try:
        opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
        for _ in range(240):
            try:
                if opener.open(f"{url}/_stcore/health", timeout=2).read() == b"ok":
                    break
            except OSError:
                time.sleep(0.25)
        time.sleep(2.0)
        seeds = [1000 + i for i in range(a.sessions)]
        want = {s: expected(s, a.runs) for s in seeds}
        sampler = Sampler(server.pid)
        sampler.start()
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            contexts = [
                browser.new_context(viewport={"width": 1300, "height": 900}, accept_downloads=True)
                for _ in seeds
            ]
            pages = []
            for c, s in zip(contexts, seeds, strict=True):
                c.set_default_timeout(a.timeout * 1000)
                p = c.new_page()
                p.goto(f"{url}/Compare?runs={a.runs}&seed={s}")
                pages.append(p)
            for p in pages:
                expect(p.get_by_role("button", name="Run", exact=True)).to_be_visible(
                    timeout=a.timeout * 1000
                )
            time.sleep(3.0)  # the first page view warms the server (imports) in a background thread
            before = rss_bytes(server.pid)  # every session open, nothing run yet
            t0 = time.monotonic()
            for p in pages:  # every session starts before any is awaited
                p.get_by_role("button", name="Run", exact=True).and_(
                    p.locator("button:not([kind=header])")
                ).click()
            done = re.compile(rf"{a.runs}/{a.runs} runs \(complete\)")
            finished, crosstalk = [], []
            for p in pages:
                expect(p.get_by_text(done).first).to_be_visible(timeout=a.timeout * 1000)
                finished.append(time.monotonic() - t0)
            wall = time.monotonic() - t0
            for p, s in zip(pages, seeds, strict=True):
                got = downloaded(p)
                if abs(got - want[s]) > 1e-9 * abs(want[s]):
                    crosstalk.append(s)
            peak = sampler.peak
            for c in contexts:
                c.close()
            browser.close()
        closed = time.monotonic()
        time.sleep(max(0.0, 20.0 - (time.monotonic() - closed)))
        soon = rss_bytes(server.pid)
        time.sleep(max(0.0, a.settle - (time.monotonic() - closed)))
        sampler.stop.set()
        after = rss_bytes(server.pid)
        mb = lambda b: f"{b / 2**20:.0f} MB"  # noqa: E731
        print(
            f"finished: {len(finished)}/{a.sessions} sessions in {wall:.1f} s "
            f"(first {min(finished):.1f} s, last {max(finished):.1f} s)"
        )
        talk = "none" if not crosstalk else f"sessions with seeds {crosstalk} got another session's numbers"
        print(f"cross-talk: {talk} (each session's metrics download against the library's own run)")
        store = a.sessions * stored_bytes(a.runs)
        print(
            f"server memory: sessions open {mb(before)}, peak {mb(peak)}; 20 s after the sessions "
            f"closed {mb(soon)} (the result store then holds the {a.sessions} finished runs, "
            f"{mb(store)}); {a.settle:.0f} s after {mb(after)} (closed sessions dropped after 120 s, "
            f"results unused for {a.ttl:.0f} s swept): {(after - before) / 2**20:+.0f} MB against "
            "before the runs"
        )
        ok = len(finished) == a.sessions and not crosstalk
    finally:
        server.terminate()
        try:
            server.wait(15)
        except subprocess.TimeoutExpired:
            server.kill()
        log.close()
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
