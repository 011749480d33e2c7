"""The contract every registered filter keeps, on every scenario it can run on.

Parametrised over ``registry()`` × ``scenario_registry()`` (contract_data.CASES): a new filter,
built in or installed as a plugin, is checked by these tests without touching them. The checks
themselves are navlab.contracts (the same ones ``navlab check-filter NAME`` runs).
"""

from __future__ import annotations

import pytest
from contract_data import CASES

from navlab import contracts as C
from navlab.filters import registry


@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_no_runtime_warning_and_finite(fkey, scenario):
    C.check_finite(fkey, scenario)


@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_stepout_shapes_and_dtypes(fkey, scenario):
    C.check_shapes(fkey, scenario)


@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_deterministic(fkey, scenario):
    C.check_deterministic(fkey, scenario)


@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_batched_equals_run_by_run(fkey, scenario):
    C.check_batched(fkey, scenario)


@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_covariance_stays_symmetric_psd(fkey, scenario):
    C.check_psd(fkey, scenario)


@pytest.mark.parametrize("outlier", [False, True], ids=["clean", "outlier"])
@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_nan_channel_is_the_update_without_that_channel(fkey, scenario, outlier):
    C.check_nan_channel(fkey, scenario, outlier)


LIMITS = [c for c in CASES if registry()[c.values[0]].kf_limit is not None]


@pytest.mark.parametrize(("fkey", "scenario"), LIMITS)
def test_declared_limit_is_the_kf(fkey, scenario):
    C.check_declared_limit(fkey, scenario)


def test_declared_limits_are_not_vacuous():
    """With their default parameters the filters that declare a limit differ from the KF (cv2d)."""
    for fkey, cls in registry().items():
        if cls.kf_limit is not None and cls.kf_limit.params:
            C.check_limit_not_vacuous(fkey)


def test_a_failed_check_says_what_differs():
    """The messages check-filter prints: what differs, where, by how much, against what tolerance."""
    a = C.cached_run("kf", "cv2d", "clean")
    b = C.Run([C._run_slice(o, 0) for o in a.outs], [])
    b.outs[2].x = b.outs[2].x + 1.0
    with pytest.raises(
        C.ContractError,
        match=r"x differs by .* σ \(largest at epoch k=3, run 0; first above tolerance at k=3; tolerance",
    ):
        C.assert_same_estimates(C.Run([C._run_slice(o, 0) for o in a.outs], []), b, 1, 1e-6, "here")


@pytest.mark.parametrize("fkey", ["irakf", "hakf"])
def test_compiled_equals_uncompiled_check(fkey):
    """The check `navlab check-filter` runs for a filter written as one-run steps (the full
    compiled-vs-uncompiled comparison of every option is tests/unit/test_jit_kernels.py)."""
    from navlab import jit

    if not jit.enabled():
        pytest.skip("numba not available")
    C.check_compiled(fkey, "cv2d")
