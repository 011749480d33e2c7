"""The contract every registered filter keeps, on every scenario it can run on.

Parametrised over ``registry()`` × ``scenario_registry()`` (contract_data.CASES): a new filter is checked
by these tests without touching them. See contract_data.py for the data and the driver.
"""

from __future__ import annotations

import numpy as np
import pytest
from contract_data import (
    CASES,
    RUNS,
    Run,
    assert_same_estimates,
    batched_P,
    cached_run,
    drive,
    filter_for,
    scenario_data,
)

from navlab.filters import SideInfo, registry
from navlab.filters.base import FLAG_NAMES, KFLimit


@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_no_runtime_warning_and_finite(fkey, scenario):
    """No NaN, overflow or division by zero inside the filter on normal data, with or without
    missing channels (the driver turns every RuntimeWarning into an error), and finite estimates.
    """
    for variant in ("normal", "gappy"):
        run = cached_run(fkey, scenario, variant)
        for o in run.outs:
            assert np.isfinite(o.x).all() and np.isfinite(o.P).all(), f"{variant}: non-finite estimate"


@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_stepout_shapes_and_dtypes(fkey, scenario):
    data = scenario_data(scenario, "gappy")
    B, n, m = RUNS, data.x0.shape[1], data.z.shape[2]
    cls = registry()[fkey]
    for o in cached_run(fkey, scenario, "gappy").outs:
        assert o.x.shape == (B, n) and o.x.dtype == np.float64
        assert np.shape(o.P) in ((n, n), (B, n, n)) and np.asarray(o.P).dtype == np.float64
        assert o.innov.shape == (B, m) and np.isfinite(o.innov).all()  # 0 on missing channels
        for name in ("S", "R_used"):
            assert np.shape(getattr(o, name)) in ((m, m), (B, m, m)), name
        assert (o.R_hat is not None) == cls.estimates_R
        if o.R_hat is not None:
            assert np.shape(o.R_hat) in ((m, m), (B, m, m))
        if o.weights is not None:
            w = np.asarray(o.weights)
            assert w.shape == (B, m) and np.isfinite(w).all() and (w >= 0).all()
        if o.flags is not None:
            f = np.asarray(o.flags)
            assert f.shape == (B, m) and np.issubdtype(f.dtype, np.integer)
            assert set(np.unique(f).tolist()) <= set(FLAG_NAMES)
        for name, v in o.stats.items():
            assert np.shape(v)[:1] == (B,), f"stats[{name!r}] has shape {np.shape(v)}, not (B, …)"
        assert ("logpdf" in o.stats) == cls.predictive_density  # the metric nlpd reads it
        if cls.predictive_density:  # finite where a measurement is, NaN where none is
            lp, ok = np.asarray(o.stats["logpdf"]), np.isfinite(o.innov) & (o.innov != 0)
            assert lp.shape == (B, m) and np.isfinite(lp[ok]).all()


@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_deterministic(fkey, scenario):
    data = scenario_data(scenario, "gappy")
    a = cached_run(fkey, scenario, "gappy")
    b = drive(filter_for(fkey, scenario), data)
    for oa, ob in zip(a.outs, b.outs, strict=True):
        np.testing.assert_array_equal(oa.x, ob.x)
        np.testing.assert_array_equal(oa.P, ob.P)
        np.testing.assert_array_equal(
            np.zeros(0) if oa.flags is None else oa.flags, np.zeros(0) if ob.flags is None else ob.flags
        )


@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_batched_equals_run_by_run(fkey, scenario):
    data = scenario_data(scenario, "gappy")
    batch = cached_run(fkey, scenario, "gappy")
    for r in range(RUNS):
        one = drive(filter_for(fkey, scenario), data, runs=slice(r, r + 1))
        part = Run([_run_slice(o, r) for o in batch.outs], [])
        assert_same_estimates(one, part, 1, 1e-7, f"run {r} alone vs in the batch")
        for oa, ob in zip(one.outs, part.outs, strict=True):
            if oa.flags is not None:
                np.testing.assert_array_equal(oa.flags, ob.flags)


def _run_slice(o, r):
    """The StepOut of run r alone (a shared P stays shared)."""
    P = np.asarray(o.P)
    return type(o)(
        x=o.x[r : r + 1],
        P=P[r : r + 1] if P.ndim == 3 else P,
        innov=o.innov[r : r + 1],
        S=o.S,
        R_used=o.R_used,
        flags=None if o.flags is None else np.asarray(o.flags)[r : r + 1],
    )


@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_covariance_stays_symmetric_psd(fkey, scenario):
    for o in cached_run(fkey, scenario, "gappy").outs:
        P = batched_P(o.P, RUNS)
        scale = np.abs(P).max(axis=(-2, -1), keepdims=True)
        assert np.all(np.abs(P - P.swapaxes(-1, -2)) <= 1e-12 * scale), "P is not symmetric"
        w = np.linalg.eigvalsh(P)
        assert np.all(w.min(axis=-1) >= -1e-9 * np.abs(w).max(axis=-1)), "P is not positive semidefinite"


class DropChannel:
    """``model`` with channel ``i`` removed (h, H, R0 and the per-channel hooks), all else delegated."""

    def __init__(self, model, i: int) -> None:
        self.base = model
        self.keep = np.array([j for j in range(model.m) if j != i])
        self.m = len(self.keep)
        self.n = model.n
        self.R0 = np.asarray(model.R0)[np.ix_(self.keep, self.keep)]
        self.linear = getattr(model, "linear", False)

    def H(self, x, k):
        return np.asarray(self.base.H(x, k))[..., self.keep, :]

    def h(self, x, k):
        return np.asarray(self.base.h(x, k))[..., self.keep]

    def __getattr__(self, name):
        attr = getattr(self.base, name)
        if name == "nn_reference":  # a per-channel hook (NNMFUKF): its channels go too
            return lambda k: np.asarray(attr(k))[..., self.keep]
        if name == "positive_skew":  # a per-channel mask (skew-t KF): its channel goes too
            return np.asarray(attr)[self.keep]
        return attr


@pytest.mark.parametrize("outlier", [False, True], ids=["clean", "outlier"])
@pytest.mark.parametrize(("fkey", "scenario"), CASES)
def test_nan_channel_is_the_update_without_that_channel(fkey, scenario, outlier):
    """A channel with NaN gets a zero gain column: the posterior equals the update with that
    channel removed from the model (first update from the same initial state) — also when another
    channel carries a 30σ outlier, so that the robust branches (down-weighting, rejection,
    covariance inflation) run with a channel missing.
    """
    data = scenario_data(scenario, "normal")
    i = 0
    z = data.z.copy()
    if outlier:
        j = data.z.shape[2] - 1
        H = np.asarray(data.model.H(data.x0, 1))
        Hj = H[..., j, :]
        s_j = np.sqrt(np.einsum("...i,ij,...j->...", Hj, np.asarray(data.P0), Hj) + data.model.R0[j, j])
        z[:, 1, j] = z[:, 1, j] + 30.0 * s_j
        data = replace_z(data, z.copy())
    z[:, 1, i] = np.nan
    full = drive(filter_for(fkey, scenario), data, z=z, epochs=1)
    small = drive(filter_for(fkey, scenario), _drop(data, i), model=DropChannel(data.model, i), epochs=1)
    # with a 30σ outlier the update is ill-conditioned (fading factors at their cap, a vague WLS
    # prior): the two formulations then agree to a few 1e-5 only, round-off amplified
    rel = 1e-4 if outlier else 1e-8
    assert_same_estimates(full, small, RUNS, rel, "NaN channel vs channel removed")
    assert np.all(full.outs[0].innov[:, i] == 0.0)  # StepOut.innov: 0 on missing channels


def replace_z(data, z):
    import dataclasses

    return dataclasses.replace(data, z=z)


def _drop(data, i):
    keep = [j for j in range(data.z.shape[2]) if j != i]

    class Dropped:
        K, x0, P0 = data.K, data.x0, data.P0
        z = data.z[:, :, keep]

        @staticmethod
        def side(k, sl=slice(None)):
            s = data.side(k, sl)
            return SideInfo(s.R_true[:, keep], s.bias[:, keep], s.outlier[:, keep], s.Q_extra)

    return Dropped()


LIMITS = [c for c in CASES if registry()[c.values[0]].kf_limit is not None]


@pytest.mark.parametrize(("fkey", "scenario"), LIMITS)
def test_declared_limit_is_the_kf(fkey, scenario):
    """With the parameters of its declared ``kf_limit`` the filter is the KF (nominal R, no outliers)."""
    lim: KFLimit = registry()[fkey].kf_limit
    data = scenario_data(scenario, "clean")
    if lim.linear_only and not getattr(data.model, "linear", False):
        pytest.skip(f"{fkey} reduces to the KF on linear models only ({lim.why})")
    got = drive(filter_for(fkey, scenario, lim.params), data)
    kf = cached_run("kf", scenario, "clean")
    assert_same_estimates(got, kf, RUNS, 1e-6, f"{fkey} with {lim.params} vs kf ({lim.why})")


def test_declared_limits_are_not_vacuous():
    """With their default parameters the filters that declare a limit differ from the KF (cv2d)."""
    kf = cached_run("kf", "cv2d", "normal")
    for fkey, cls in registry().items():
        if cls.kf_limit is None or not cls.kf_limit.params:
            continue
        run = cached_run(fkey, "cv2d", "normal")
        dx = max(np.abs(a.x - b.x).max() for a, b in zip(run.outs, kf.outs, strict=True))
        assert dx > 1e-6, f"{fkey}: default parameters give the KF on cv2d: the limit test proves nothing"
