"""Shared by every test directory: each test process has a results store of its own.

``NAVLAB_STORE`` points at a fresh folder under the process's pytest temp dir for the whole
session, so no test reads a result another run (or the developer's own store) left, and under
pytest-xdist each worker (and the streamlit servers and CLI subprocesses it starts, which inherit
the environment) writes to its own folder. Tests that need their own store still set one.
"""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session", autouse=True)
def _a_results_store_per_test_process(tmp_path_factory: pytest.TempPathFactory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NAVLAB_STORE", str(tmp_path_factory.mktemp("navlab-store")))
        yield
