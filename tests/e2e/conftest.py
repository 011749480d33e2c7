"""Browser tests: Playwright drives Debian's Chromium against a real ``streamlit run``.

* ``app_server`` starts ``python -m streamlit run app.py`` on a free loopback port for the session
  and yields its base URL. With ``NAVLAB_E2E_URL`` set (e.g. ``http://127.0.0.1:8503`` for a
  container started by ``KEEP=1 ../shared/tools/verify-docker.sh .``) it uses that server instead.
* ``fresh_server`` starts a separate, never-visited server for one test (first-visitor checks).
* ``base_url`` is the same URL, so ``page.goto("/?seed=42")`` works in tests.
* Every test under tests/e2e is marked ``e2e`` and ``slow`` (a browser and a server: seconds each,
  so ``-m "not slow"`` leaves them out) and is skipped when /usr/bin/chromium is missing
  (``apt-get install -y chromium``; ``playwright install`` cannot download browsers here).
* Under pytest-xdist every worker starts its own servers (free ports, logs named after the worker,
  the worker's own results store: tests/conftest.py) and its own browser.
* ``page`` is one browser tab per test process, reused by test after test (at the viewport of the
  test module's ``browser_context_args``); after each test it leaves for about:blank (ending the
  test's Streamlit session) with the app's cookies and storage cleared. Opening a page in a new tab
  costs Chromium about twice what a navigation in a used tab does (a new renderer process; 8 pages
  in presentation mode: 36 s in new contexts, 18 s in one tab), and every test opens its page
  with ``page.goto``: a new document and a new Streamlit session either way. Tests that need
  several sessions at once, or to close a browser context, make their own contexts.
"""

from __future__ import annotations

import contextlib
import functools
import os
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
from playwright.sync_api import Browser, BrowserContext, Page

ROOT = Path(__file__).resolve().parents[2]
E2E_DIR = Path(__file__).resolve().parent
ARTIFACTS_DIR = E2E_DIR / "_artifacts"
CHROMIUM = Path("/usr/bin/chromium")
DEFAULT_VIEWPORT = {"width": 1280, "height": 720}  # Playwright's, for a module that sets none
HEALTH_TIMEOUT_S = 60.0
WAIT_MS = 90_000  # every browser wait: the machine is shared and runs may queue (a 30 s default
# wait once timed out in CI one time in three)

# Without the background-networking flags Chromium floods this machine's closed network.
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


@pytest.hookimpl(tryfirst=True)  # before `-m` deselection sees the items
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    skip = pytest.mark.skip(reason=f"{CHROMIUM} not found: apt-get install -y chromium")
    for item in items:
        if E2E_DIR in Path(item.path).parents:
            item.add_marker(pytest.mark.e2e)
            item.add_marker(pytest.mark.slow)
            if not CHROMIUM.exists():
                item.add_marker(skip)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _health(url: str) -> str | None:
    """Body of ``url``/_stcore/health, or None while it does not answer."""
    # bypass any proxy settings: the server is on loopback
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    try:
        with opener.open(f"{url}/_stcore/health", timeout=2) as r:
            return r.read().decode().strip()
    except (urllib.error.URLError, OSError):
        return None


def _wait_healthy(url: str, proc: subprocess.Popen | None, log: Path | None) -> None:
    deadline = time.monotonic() + HEALTH_TIMEOUT_S
    while time.monotonic() < deadline:
        if _health(url) == "ok":
            return
        if proc is not None and proc.poll() is not None:
            tail = log.read_text(errors="replace")[-3000:] if log else ""
            pytest.fail(f"streamlit exited with code {proc.returncode} before it was healthy:\n{tail}")
        time.sleep(0.25)
    pytest.fail(f"{url}/_stcore/health did not answer 'ok' within {HEALTH_TIMEOUT_S:.0f} s")


@pytest.fixture(autouse=True)
def _long_waits(request: pytest.FixtureRequest) -> None:
    """Every wait of every browser test uses the suite's long timeout: Playwright's default
    actions (30 s), navigations and expect() assertions (5 s) alike."""
    from playwright.sync_api import expect

    expect.set_options(timeout=WAIT_MS)
    for name in ("page", "context"):
        if name in request.fixturenames:
            obj = request.getfixturevalue(name)
            obj.set_default_timeout(WAIT_MS)
            obj.set_default_navigation_timeout(WAIT_MS)


def log_name(stem: str) -> str:
    """``stem``.log, or ``stem``-gw0.log in xdist worker gw0 (each worker has its own servers)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    return f"{stem}-{worker}.log" if worker else f"{stem}.log"


@pytest.fixture(scope="session")
def artifacts_dir() -> Path:
    """Folder for screenshots and logs a human may look at (gitignored)."""
    ARTIFACTS_DIR.mkdir(parents=True, exist_ok=True)
    return ARTIFACTS_DIR


@functools.cache
def _warm_kernels() -> None:
    """Compile (or load from numba's disk cache) navlab's kernels once per test process, before a
    server starts: on a fresh checkout a server compiling them in front of the browser took a Learn
    page past its 90 s wait (the Docker image compiles them at build time, as this does).
    """
    from navlab.warmup import warm

    warm()


@contextlib.contextmanager
def serve(log: Path) -> Iterator[str]:
    """Start ``streamlit run app.py`` on a free loopback port; yield its URL; stop it."""
    if not (ROOT / "app.py").exists():
        pytest.fail(f"{ROOT / 'app.py'} not found: nothing to serve")
    _warm_kernels()
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    cmd = [
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
    ]
    with log.open("w") as out:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT)
    try:
        _wait_healthy(url, proc, log)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _external_url() -> str | None:
    external = os.environ.get("NAVLAB_E2E_URL", "").strip()
    return external.rstrip("/") if external else None


@pytest.fixture(scope="session")
def app_server(artifacts_dir: Path) -> Iterator[str]:
    """Base URL of a healthy navlab server, without a trailing slash."""
    url = _external_url()
    if url:
        _wait_healthy(url, None, None)
        yield url
        return
    with serve(artifacts_dir / log_name("streamlit-server")) as url:
        yield url


@pytest.fixture
def fresh_server(artifacts_dir: Path) -> Iterator[str]:
    """A server nobody has visited yet (catches first-visitor bugs such as the pages/ deep-link
    bug). Against an external server (``NAVLAB_E2E_URL``, e.g. a just-started container) it is
    that server."""
    url = _external_url()
    if url:
        _wait_healthy(url, None, None)
        yield url
        return
    with serve(artifacts_dir / log_name("streamlit-server-fresh")) as url:
        yield url


@pytest.fixture(scope="session")
def base_url(app_server: str) -> str:
    """pytest-playwright passes this to every browser context: relative ``page.goto`` works."""
    return app_server


@pytest.fixture(scope="session")
def browser_type_launch_args(browser_type_launch_args: dict) -> dict:
    """Launch Debian's Chromium (no downloaded browsers) with flags for this closed network."""
    return {
        **browser_type_launch_args,
        "executable_path": str(CHROMIUM),
        "args": [*browser_type_launch_args.get("args", []), *CHROMIUM_ARGS],
    }


@pytest.fixture(scope="session")
def _shared_tab(browser: Browser, base_url: str) -> Iterator[dict]:
    """The test process's browser context and the tab its tests reuse (``{"context", "page"}``)."""
    ctx: BrowserContext = browser.new_context(base_url=base_url, accept_downloads=True)
    ctx.set_default_timeout(WAIT_MS)
    ctx.set_default_navigation_timeout(WAIT_MS)
    tab = {"context": ctx, "page": None}
    yield tab
    ctx.close()


@pytest.fixture
def page(_shared_tab: dict, browser_context_args: dict) -> Iterator[Page]:
    """The reused tab, at the module's viewport (replaces pytest-playwright's new tab per test)."""
    p: Page | None = _shared_tab["page"]
    if p is None or p.is_closed():
        p = _shared_tab["page"] = _shared_tab["context"].new_page()
    p.set_viewport_size(browser_context_args.get("viewport") or DEFAULT_VIEWPORT)
    yield p
    try:  # leave the app: its session ends as when a tab closes; forget its cookies and storage
        if p.url.startswith("http"):
            p.evaluate("() => { localStorage.clear(); sessionStorage.clear(); }")
        p.goto("about:blank")
        _shared_tab["context"].clear_cookies()
    except Exception:  # a broken tab: the next test gets a new one
        with contextlib.suppress(Exception):
            p.close()
        _shared_tab["page"] = None
