"""A user's filter as a plugin (examples/plugin): pip-installed into a fresh virtual environment, it
shows in ``navlab list filters`` and on the Compare page and passes ``navlab check-filter``; a copy
with a sign error in its update fails check-filter with a message that says what differs.

The environments are made with ``--system-site-packages`` (navlab's dependencies come from the
running interpreter's environment; only the plugin is installed into the venv) and this checkout
first on PYTHONPATH, so the navlab under test is this one. pip builds the plugin's wheel once per
test session (from a copy of examples/plugin, with build isolation, as a user's ``pip install``
does); each environment is a venv without a pip of its own into which this interpreter's pip
installs that wheel (``pip --python``): about 1.5 s an environment instead of 10 s (ensurepip and
a build each time). The broken copies are that wheel installed, then the installed module edited
(a pure-Python package: the same files a pip install of an edited copy leaves).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PLUGIN = ROOT / "examples" / "plugin"

pytestmark = pytest.mark.slow


def _pip(*args: str) -> None:
    subprocess.run(
        [sys.executable, "-m", "pip", *args],
        check=True,
        env={**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"},
    )


@pytest.fixture(scope="session")
def plugin_wheel(tmp_path_factory) -> Path:
    """examples/plugin built into a wheel, once (pip builds in a copy of the source: not in the repo)."""
    tmp = tmp_path_factory.mktemp("plugin-wheel")
    src = shutil.copytree(PLUGIN, tmp / "src")
    _pip("wheel", "--quiet", "--no-deps", "--wheel-dir", str(tmp / "dist"), str(src))
    (wheel,) = (tmp / "dist").glob("navlab_fading-*.whl")
    return wheel


def _venv_with(tmp: Path, wheel: Path) -> Path:
    """A fresh venv at tmp/venv with ``wheel`` pip-installed; its python."""
    subprocess.run(
        [sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", str(tmp / "venv")],
        check=True,
    )
    py = tmp / "venv" / "bin" / "python"
    # --no-deps: navlab and numpy are the running environment's (seen through system site-packages)
    _pip("--python", str(py), "install", "--quiet", "--no-deps", "--no-index", "--no-compile", str(wheel))
    return py


def _installed(py: Path, relpath: str) -> Path:
    """A file of the package installed for ``py`` (its purelib site-packages)."""
    purelib = subprocess.run(
        [str(py), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    path = Path(purelib) / relpath
    assert path.is_file(), path
    return path


def _navlab(py: Path, *args: str, tmp: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NAVLAB_STORE": str(tmp / "store")}
    return subprocess.run(
        [str(py), "-m", "navlab", *args], capture_output=True, text=True, env=env, cwd=tmp, timeout=600
    )


@pytest.fixture(scope="module")
def plugin_python(tmp_path_factory, plugin_wheel) -> Path:
    return _venv_with(tmp_path_factory.mktemp("plugin"), plugin_wheel)


def test_the_plugin_is_listed_and_passes_check_filter(plugin_python, tmp_path):
    listed = _navlab(plugin_python, "list", "filters", "--format", "csv", tmp=tmp_path)
    assert listed.returncode == 0, listed.stderr
    row = next(line for line in listed.stdout.splitlines() if line.startswith("fading-kf,"))
    assert "Fading-memory KF" in row and "navlab-fading 0.1.0" in row
    checked = _navlab(plugin_python, "check-filter", "fading-kf", "-v", tmp=tmp_path)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert "fading-kf: passed" in checked.stdout
    assert "FAIL" not in checked.stdout
    # the contracts that matter ran (not all skipped): every one passed at least on cv2d
    passed = [line for line in checked.stdout.splitlines() if line.startswith("pass") and "[cv2d]" in line]
    for name in ("batched = run by run", "P symmetric PSD", "NaN channel", "declared KF limit", "reference"):
        assert any(name in line for line in passed), name


def test_the_plugin_is_on_the_compare_page_and_the_others(plugin_python, tmp_path):
    script = textwrap.dedent(
        f"""
        from streamlit.testing.v1 import AppTest
        at = AppTest.from_file({str(ROOT / "app.py")!r}, default_timeout=300)
        at.run()
        at.switch_page("pages/1_Compare.py")
        q = {{"runs": "6", "sc.cv2d.epochs": "30", "flt": ["kf", "fading-kf"]}}
        for k, v in q.items():
            at.query_params[k] = v
        at.run()
        assert "fading-kf" in at.multiselect(key="flt").options or "Fading-memory KF" in str(
            at.multiselect(key="flt").options
        ), at.multiselect(key="flt").options
        at.button(key="run_compare").click().run()
        assert not at.exception, [e.value for e in at.exception]
        assert not at.error, [e.value for e in at.error]
        print("ROWS", list(at.table[0].value.index))
        learn = ("pages/5_Learn.py", {{"filter": "fading-kf"}})
        others = (learn, ("pages/3_Sweep.py", {{"flt": ["kf", "fading-kf"]}}))
        for page, q in others:
            other = AppTest.from_file({str(ROOT / "app.py")!r}, default_timeout=300)
            other.run()
            other.switch_page(page)
            for k, v in q.items():
                other.query_params[k] = v
            other.run()
            assert not other.exception and not other.error, (page, [e.value for e in other.exception])
        """
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NAVLAB_STORE": str(tmp_path / "store")}
    done = subprocess.run(
        [str(plugin_python), "-c", script], capture_output=True, text=True, env=env, cwd=ROOT, timeout=900
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "Fading-memory KF" in done.stdout.split("ROWS", 1)[1]


def test_a_sign_error_fails_check_filter_readably(tmp_path, plugin_wheel):
    py = _venv_with(tmp_path, plugin_wheel)
    flt = _installed(py, "navlab_fading/filter.py")
    code = flt.read_text()
    assert "x = x + (K @ nu" in code
    flt.write_text(code.replace("x = x + (K @ nu", "x = x - (K @ nu"))  # the sign error
    out = _navlab(py, "check-filter", "fading-kf", "--scenario", "cv2d", tmp=tmp_path)
    assert out.returncode == 1, out.stdout + out.stderr
    assert "fading-kf: FAILED" in out.stdout
    fails = [line for line in out.stdout.splitlines() if line.startswith("FAIL")]
    # in words: which contract, on which scenario, what differs, by how much, where
    assert any(
        "equals its reference [cv2d]" in line
        and "x differs from the reference by" in line
        and "epoch k=1" in line
        for line in fails
    ), fails
    assert any("declared KF limit [cv2d]" in line and "vs kf" in line for line in fails), fails
    assert "Traceback" not in out.stdout + out.stderr


def test_a_plugin_that_fails_to_import_is_named_not_fatal(tmp_path, plugin_wheel):
    py = _venv_with(tmp_path, plugin_wheel)
    _installed(py, "navlab_fading/filter.py").write_text("raise ImportError('no such thing as fading')\n")
    listed = _navlab(py, "list", "filters", tmp=tmp_path)
    assert listed.returncode == 0 and "kf" in listed.stdout  # navlab still works
    assert "fading-kf" in listed.stderr and "no such thing as fading" in listed.stderr  # logged
    out = _navlab(py, "check-filter", "fading-kf", tmp=tmp_path)
    assert out.returncode == 2
    assert "plugin 'fading-kf' failed to load" in out.stderr and "navlab-fading 0.1.0" in out.stderr
