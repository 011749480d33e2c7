"""Shared by the opt-in container tests: where verify-docker.sh lives, a free port, and the
checks that skip them cleanly (not selected, tools missing, not root)."""

from __future__ import annotations

import os
import re
import shutil
import socket
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
VERIFY_DOCKER = ROOT.parent / "shared" / "tools" / "verify-docker.sh"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def require_container_tools(request, chromium: bool = False) -> None:
    """Skip unless docker tests were asked for and podman/buildah (and Chromium), root are here."""
    markexpr = request.config.getoption("markexpr") or ""
    selected = re.search(r"(?<!not )\bdocker\b", markexpr) is not None
    if not (selected or os.environ.get("NAVLAB_DOCKER") == "1"):
        pytest.skip("opt-in: run with `python -m pytest -m docker` or NAVLAB_DOCKER=1")
    if not VERIFY_DOCKER.exists():
        pytest.skip(f"{VERIFY_DOCKER} not found (../shared must sit beside the repository)")
    missing = [t for t in ("podman", "buildah") if shutil.which(t) is None]
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed (apt-get install -y podman buildah runc)")
    if chromium and not Path("/usr/bin/chromium").exists():
        pytest.skip("/usr/bin/chromium not found: apt-get install -y chromium")
    if os.geteuid() != 0:
        pytest.skip("verify-docker.sh needs root")
