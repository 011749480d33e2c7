"""Fixtures for the AppTest page tests; the helpers live in apphelpers.py (import from there)."""

from __future__ import annotations

import pytest
from apphelpers import _open


@pytest.fixture(autouse=True)
def _tasks_here(monkeypatch, tmp_path):
    """Sweep/Tune tasks in the test process (no cluster per test) and a fresh results store."""
    monkeypatch.setenv("NAVLAB_DASK_SCHEDULER", "serial")
    monkeypatch.setenv("NAVLAB_STORE", str(tmp_path / "store"))


@pytest.fixture
def open_page():
    """``open_page(path, **query)``: start at app.py with URL query parameters, switch, run."""
    return _open
