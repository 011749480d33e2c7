"""navlab's layers, as import-linter contracts (pyproject.toml [tool.importlinter]), hold.

`lint-imports` fails on an import from a lower layer into a higher one (e.g. navlab.metrics
importing navlab.scenarios) and on streamlit imported outside navlab.ui, directly or through
another navlab module.
"""

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _lint_imports() -> str:
    beside = Path(sys.executable).with_name("lint-imports")  # this interpreter's install
    found = str(beside) if beside.exists() else shutil.which("lint-imports")
    assert found, "lint-imports is missing: pip install -r requirements-dev.txt"
    return found


def test_the_import_contracts_are_kept():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}  # this checkout's navlab, installed or not
    out = subprocess.run(
        [_lint_imports(), "--no-cache"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode == 0, out.stdout + out.stderr


def test_the_streamlit_contract_covers_every_layer_but_the_app():
    """A module given a layer is also kept from streamlit (the forbidden contract lists them)."""
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    layers, forbidden = (next(c for c in cfg["contracts"] if c["type"] == t) for t in ("layers", "forbidden"))
    names = {n.strip() for layer in layers["layers"] for n in layer.replace(":", "|").split("|")}
    assert set(forbidden["source_modules"]) == {f"navlab.{n}" for n in names - {"ui"}}
    assert forbidden["forbidden_modules"] == ["streamlit"]
