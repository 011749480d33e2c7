"""Random streams by blocks of runs, and the simulated truth: run r is the same in any batch."""

import numpy as np
import pytest

from navlab.noise import make_outliers, make_schedule
from navlab.scenarios import base, make_scenario
from navlab.scenarios.base import BLOCK_RUNS, ScenarioData, propagate, run_streams

SIMULATED = {
    "cv2d": {"epochs": 30},
    "sins-gps": {"epochs": 30},
    "gps-ins-rtk": {"epochs": 40, "anomaly_start": 10, "anomaly_stop": 20, "gross_start": 5},
    "gps-ins-pseudorange": {"epochs": 30},
}
OUTLIERS = {
    "none": {},
    "mixture": {"contamination": 0.2},
    "isolated": {"start": 3, "stop": 20, "every": 4},
    "student-t": {"dof": 3.0},
}
PER_RUN = ScenarioData.PER_RUN


def test_a_run_draws_the_same_numbers_alone_in_a_chunk_or_in_a_batch():
    runs = np.arange(BLOCK_RUNS - 5, BLOCK_RUNS + 7)  # across a block boundary
    whole = run_streams(3, runs)
    want = [whole.truth.standard_normal((4, 2)), whole.meas.random(5), whole.meas.chisquare(3.0, 2)]
    for chunk in (1, 2, 5, 12):
        got = [[], [], []]
        for i in range(0, len(runs), chunk):
            s = run_streams(3, runs[i : i + chunk])
            for j, a in enumerate(
                (s.truth.standard_normal((4, 2)), s.meas.random(5), s.meas.chisquare(3.0, 2))
            ):
                got[j].append(a)
        for w, g in zip(want, got, strict=True):
            np.testing.assert_array_equal(np.concatenate(g), w)
    # any order and repeats: rows follow the runs asked for
    s = run_streams(3, runs[[7, 0, 7]])
    np.testing.assert_array_equal(s.truth.standard_normal((4, 2)), want[0][[7, 0, 7]])


def test_streams_runs_and_seeds_are_distinct_and_normal():
    s = run_streams(1, range(2 * BLOCK_RUNS))
    t, m, i, a = (x.standard_normal(500) for x in (s.truth, s.meas, s.init, s.aux))
    draws = np.stack([t, m, i, a])  # (4 streams, B runs, 500)
    flat = draws.reshape(-1, 500)
    corr = np.corrcoef(flat)[np.triu_indices(flat.shape[0], 1)]
    assert np.abs(corr).max() < 0.3  # no two (stream, run) rows are the same or close
    assert abs(draws.mean()) < 4 / np.sqrt(draws.size)
    assert abs(draws.var() - 1) < 4 * np.sqrt(2 / draws.size)
    other = run_streams(2, range(2 * BLOCK_RUNS)).truth.standard_normal(500)
    assert not np.array_equal(other, t)
    u = s.meas.random((3, 1000))
    assert u.min() >= 0.0 and u.max() < 1.0


def test_runs_must_be_indices():
    with pytest.raises(ValueError, match="run indices"):
        run_streams(1, [0.5])
    with pytest.raises(ValueError, match="run indices"):
        run_streams(1, [-1])
    assert run_streams(1, []).truth.standard_normal(3).shape == (0, 3)


@pytest.mark.parametrize("outliers", sorted(OUTLIERS))
@pytest.mark.parametrize("key", sorted(SIMULATED))
def test_simulate_is_the_same_in_one_batch_and_in_chunks(key, outliers):
    scen = make_scenario(key, SIMULATED[key])
    sched, outl = make_schedule("constant"), make_outliers(outliers, OUTLIERS[outliers])
    whole = scen.simulate(sched, outl, list(range(10)), 4)
    parts = [scen.simulate(sched, outl, list(r), 4) for r in ([0, 1, 2], [3], [4, 5, 6, 7, 8, 9])]
    for f in PER_RUN:
        np.testing.assert_array_equal(np.concatenate([getattr(p, f) for p in parts]), getattr(whole, f))
    far = scen.simulate(sched, outl, [9, 200], 4)  # another block, other runs beside it
    for f in PER_RUN:
        np.testing.assert_array_equal(getattr(far, f)[0], getattr(whole, f)[9])


@pytest.mark.parametrize("key", sorted(SIMULATED))
def test_the_outlier_model_and_schedule_do_not_change_the_truth(key):
    scen = make_scenario(key, SIMULATED[key])
    a = scen.simulate(make_schedule("constant"), make_outliers("none"), [0, 1, 70], 5)
    b = scen.simulate(make_schedule("step"), make_outliers("student-t"), [0, 1, 70], 5)
    np.testing.assert_array_equal(a.x_true, b.x_true)
    np.testing.assert_array_equal(a.x0, b.x0)
    assert not np.array_equal(a.z[:, 1:], b.z[:, 1:])


def _case(B=7, K=40, n=5, ne=3, seed=0):
    rng = np.random.default_rng(seed)
    Phi = np.eye(n) + 0.1 * rng.standard_normal((K + 1, n, n))
    L = rng.standard_normal((K + 1, n, ne))
    return (
        rng.standard_normal((B, n)),
        Phi,
        rng.standard_normal((B, K, ne)),
        L,
        rng.standard_normal((B, K, n)),
    )


def _textbook(x0, Phi, e, L, u):
    x = np.empty((e.shape[0], e.shape[1] + 1, x0.shape[1]))
    x[:, 0] = x0
    for k in range(1, e.shape[1] + 1):
        Fk = Phi if Phi.ndim == 2 else Phi[k]
        Lk = L if L.ndim == 2 else L[k]
        x[:, k] = x[:, k - 1] @ Fk.T + e[:, k - 1] @ Lk.T + (0 if u is None else u[:, k - 1])
    return x


@pytest.fixture(params=["compiled", "numpy"])
def path(request, monkeypatch):
    if request.param == "numpy":
        monkeypatch.setattr(base._PROPAGATE, "get", lambda: None)
    elif base._PROPAGATE.get() is None:
        pytest.skip("numba not available")
    else:
        monkeypatch.setattr(base, "COMPILED_FROM_MACS", 0)  # the compiled path even for short runs
    return request.param


@pytest.mark.parametrize("form", ["stacked", "constant", "no L", "no u"])
def test_propagate_is_the_linear_recursion_and_the_same_for_a_run_alone(path, form):
    x0, Phi, e, L, u = _case()
    n = x0.shape[1]
    if form == "constant":
        Phi, L = Phi[3], L[3]
    if form == "no L":
        L, e = None, np.random.default_rng(1).standard_normal((7, 40, n))
    if form == "no u":
        u = None
    x = propagate(x0, Phi, e, L, u)
    ref = _textbook(x0, Phi, e, np.eye(n) if L is None else L, u)
    np.testing.assert_allclose(x, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    for r in (0, 6):
        one = propagate(x0[[r]], Phi, e[[r]], L, None if u is None else u[[r]])
        np.testing.assert_array_equal(one[0], x[r])  # the same bits alone or in the batch


def test_compiled_and_numpy_propagation_are_the_same_bits(monkeypatch):
    """Both paths make the same IEEE operations in the same order (no FMA, no BLAS)."""
    if base._PROPAGATE.get() is None:
        pytest.skip("numba not available")
    x0, Phi, e, L, u = _case(B=50, K=300, n=15, ne=15, seed=3)
    assert base.COMPILED_FROM_MACS <= 300 * 15 * 30  # this size takes the compiled path
    fast = propagate(x0, Phi, e, L, u)
    monkeypatch.setattr(base._PROPAGATE, "get", lambda: None)
    slow = propagate(x0, Phi, e, L, u)
    np.testing.assert_array_equal(fast, slow)
