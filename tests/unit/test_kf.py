"""The standard KF against FilterPy (an independent implementation) and simple limits."""

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from linmodels import random_model, side

from navlab.filters import LinearModel, make_filter


@pytest.mark.parametrize(("n", "m", "seed"), [(4, 2, 0), (3, 3, 1), (6, 1, 2), (2, 4, 3)])
def test_kf_equals_filterpy(n, m, seed):
    rng = np.random.default_rng(seed)
    F, Q, H, R = random_model(rng, n, m)
    model = LinearModel(F, Q, H, R)
    x0 = rng.standard_normal(n)
    P0 = np.diag(rng.uniform(0.5, 2.0, n))
    zs = rng.standard_normal((30, m)) * 3

    ref = KalmanFilter(dim_x=n, dim_z=m)
    ref.x, ref.P, ref.F, ref.Q, ref.H, ref.R = x0.copy(), P0.copy(), F, Q, H, R
    kf = make_filter("kf")
    st = kf.init(model, x0[None], P0)
    for k, z in enumerate(zs, start=1):
        ref.predict()
        ref.update(z)
        st = kf.predict(model, st, k)
        st, out = kf.update(model, st, k, z[None], side(1, m))
        np.testing.assert_allclose(out.x[0], ref.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.broadcast_to(out.P, (1, n, n))[0], ref.P, rtol=0, atol=1e-9)
        np.testing.assert_allclose(out.innov[0], ref.y, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.broadcast_to(out.S, (1, m, m))[0], ref.S, atol=1e-9)


def test_kf_missing_channel_is_skipped():
    """A NaN channel must equal an update with that row of H removed."""
    rng = np.random.default_rng(5)
    F, Q, H, R = random_model(rng, 4, 2)
    R = np.diag(np.diag(R))  # a dropped channel is independent only with a diagonal R
    x0, P0 = rng.standard_normal(4), np.eye(4)
    z = np.array([[1.3, np.nan]])
    kf = make_filter("kf")
    st = kf.predict(LinearModel(F, Q, H, R), kf.init(LinearModel(F, Q, H, R), x0[None], P0), 1)
    _, out = kf.update(LinearModel(F, Q, H, R), st, 1, z, side(1, 2))
    m1 = LinearModel(F, Q, H[:1], R[:1, :1])
    st1 = kf.predict(m1, kf.init(m1, x0[None], P0), 1)
    _, out1 = kf.update(m1, st1, 1, z[:, :1], side(1, 1))
    np.testing.assert_allclose(out.x, out1.x, atol=1e-12)
    np.testing.assert_allclose(out.P, np.broadcast_to(out1.P, out.P.shape), atol=1e-12)
    assert np.isfinite(out.x).all()


def test_huge_R_means_no_correction():
    rng = np.random.default_rng(7)
    F, Q, H, _ = random_model(rng, 3, 2)
    model = LinearModel(F, Q, H, 1e12 * np.eye(2))
    kf = make_filter("kf")
    st = kf.predict(model, kf.init(model, np.ones((2, 3)), np.eye(3)), 1)
    _, out = kf.update(model, st, 1, np.full((2, 2), 50.0), side(2, 2))
    np.testing.assert_allclose(out.x, st.x, atol=1e-9)
