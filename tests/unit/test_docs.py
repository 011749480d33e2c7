"""The documentation: the MkDocs site builds with --strict (no broken link, no missing snippet, no
docstring the API pages cannot render), its generated pages hold what they promise, and the README
stays short with every link resolving.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_readme_is_short_and_its_links_resolve():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    links = re.findall(r"\]\(([^)#\s]+)\)", text)
    local = [t for t in links if "://" not in t]
    assert local, "the README links the docs pages"
    for target in local:
        assert (ROOT / target).exists(), target


@pytest.mark.slow
def test_mkdocs_build_strict(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NO_MKDOCS_2_WARNING": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    site = tmp_path / "site"
    cli = (site / "cli-reference" / "index.html").read_text()
    for cmd in ("list", "run", "reproduce", "sweep", "tune", "check-filter", "app"):
        assert f"navlab {cmd}" in cli, cmd  # generated from the parser
    assert "--save-results" in cli and "latex" in cli
    tutorial = (site / "add-a-filter" / "index.html").read_text()
    assert "FadingKF" in tutorial and "fading_kf" in tutorial  # the example package's code, included
    assert "--8&lt;--" not in tutorial  # every snippet include resolved
    filters = (site / "filters" / "index.html").read_text()
    assert "huber-kf" in filters and "<table>" in filters  # every filter with its Params
    api = (site / "api" / "index.html").read_text()
    assert "to_xarray" in api and "check_filter" in api  # from the docstrings
