"""The browser suite (tests/e2e) against the real container image.

Builds and starts the image with ``KEEP=1 ../shared/tools/verify-docker.sh . PORT`` (buildah +
podman; root), then runs ``pytest tests/e2e`` with ``NAVLAB_E2E_URL`` pointing at the container's
published port, and removes the container. Opt-in like the other docker test:
``python -m pytest -m docker`` or ``NAVLAB_DOCKER=1``; skipped cleanly when the tools are missing.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from dockerhelpers import ROOT, VERIFY_DOCKER, free_port, require_container_tools

CONTAINER = "navlab-verify"  # the name verify-docker.sh gives its container


def _remove_container() -> None:
    """Remove the container this test started."""
    subprocess.run(
        ["podman", "--runtime", "runc", "rm", "-f", CONTAINER], capture_output=True, check=False, timeout=120
    )


@pytest.mark.docker
@pytest.mark.slow
def test_browser_suite_against_the_container(request):
    require_container_tools(request, chromium=True)

    exists = subprocess.run(
        ["podman", "container", "exists", CONTAINER], capture_output=True, check=False, timeout=60
    )
    if exists.returncode == 0:
        pytest.skip(
            f"a container named {CONTAINER} already runs (someone else's verify-docker "
            f"run?); remove it with `podman --runtime runc rm -f {CONTAINER}` first"
        )
    port = free_port()
    try:
        build = subprocess.run(
            ["bash", str(VERIFY_DOCKER), str(ROOT), str(port)],
            env={**os.environ, "KEEP": "1"},
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=25 * 60,
            check=False,
        )
        assert build.returncode == 0, (build.stdout[-4000:], build.stderr[-4000:])
        assert "left running" in build.stdout
        e2e = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/e2e"],
            cwd=ROOT,
            env={**os.environ, "NAVLAB_E2E_URL": f"http://127.0.0.1:{port}"},
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=30 * 60,
            check=False,
        )
        assert e2e.returncode == 0, e2e.stdout[-6000:] + e2e.stderr[-3000:]
        assert " passed" in e2e.stdout
    finally:
        _remove_container()
