"""Shared by every test directory: each test process has a results store of its own, and the test
modules are collected in the order that keeps both xdist workers busy to the end.

``NAVLAB_STORE`` points at a fresh folder under the process's pytest temp dir for the whole
session, so no test reads a result another run (or the developer's own store) left, and under
pytest-xdist each worker (and the streamlit servers and CLI subprocesses it starts, which inherit
the environment) writes to its own folder. Tests that need their own store still set one.

The test command's ``-n 2 --dist loadscope --no-loadscope-reorder`` hands whole modules to the two
workers in collection order, which this file sets: first the big parametrized modules (PARAMETRIZED
tests or more: the contracts, the pinned outputs), which compile the filters' kernels into numba's
disk cache; then the browser modules (tests/e2e), the longest; then the modules with a test marked
``slow``; then the rest, each group by number of tests. xdist's own order (by number of tests) handed
out the browser modules last, a long module keeping one worker busy while the other had nothing
left; the browser modules first, on a fresh checkout, made their servers compile the kernels while
the browser waited (a Learn page took over the 90 s wait on a loaded machine).
"""

from __future__ import annotations

from pathlib import Path

import pytest

PARAMETRIZED = 50


@pytest.hookimpl(trylast=True)  # after tests/e2e and tests/contract have marked their tests
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    count: dict[Path, int] = {}
    for item in items:
        count[item.path] = count.get(item.path, 0) + 1
    rank: dict[Path, int] = {}
    for item in items:
        if count[item.path] >= PARAMETRIZED:
            r = 0
        else:
            r = 1 if item.get_closest_marker("e2e") else 2 if item.get_closest_marker("slow") else 3
        rank[item.path] = min(r, rank.get(item.path, r))
    # stable: pytest's order within a module
    items.sort(key=lambda item: (rank[item.path], -count[item.path]))


@pytest.fixture(scope="session", autouse=True)
def _a_results_store_per_test_process(tmp_path_factory: pytest.TempPathFactory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NAVLAB_STORE", str(tmp_path_factory.mktemp("navlab-store")))
        yield
