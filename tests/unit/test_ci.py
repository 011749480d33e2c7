"""CI (.ci/run) runs the README's test command, word for word."""

from __future__ import annotations

import shlex
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SETUP = "python -m pip install -e . -r requirements-dev.txt && "


def test_ci_runs_the_readme_test_command():
    (line,) = [s for s in (ROOT / "README.md").read_text().splitlines() if s.startswith(SETUP)]
    readme = line.removeprefix(SETUP)
    (ci,) = [s.strip() for s in (ROOT / ".ci" / "run").read_text().splitlines() if "-m pytest" in s]
    assert shlex.split(ci.split(" || ")[0]) == shlex.split(readme)
