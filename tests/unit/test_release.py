"""The version is one number: navlab.__version__, printed by --version, in CITATION.cff, in the changelog."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import navlab
from navlab.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_version_flag_prints_the_package_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"navlab {navlab.__version__}"


def test_citation_and_changelog_carry_the_version():
    cff = (ROOT / "CITATION.cff").read_text()
    assert re.search(r"^cff-version: 1\.2\.0$", cff, re.M)
    assert re.search(rf"^version: {re.escape(navlab.__version__)}$", cff, re.M)
    for field in ("title", "authors", "message"):
        assert re.search(rf"^{field}:", cff, re.M), field
    log = (ROOT / "CHANGELOG.md").read_text()
    assert f"## [{navlab.__version__}]" in log
