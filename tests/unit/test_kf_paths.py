"""benchmarks/kf_paths.py's one-run KF steps compute what the batched KF family does.

The benchmark times the KF family's batched predict/update against the one-run textbook step
compiled and looped over the runs (issue 23); these tests make sure both compute the same numbers
(to round-off), missing channels (NaN in z) included, so the figures compare like with like.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from navlab.experiment import ExperimentSpec, plan
from navlab.filters import make_filter
from navlab.filters.kalman import kf_update, measurement_prediction
from navlab.jit import numpy_paths
from navlab.linalg import joseph_from_gain, kf_gain, mv, predict_cov, sym, zero_columns

_spec = importlib.util.spec_from_file_location(
    "kf_paths", Path(__file__).resolve().parents[2] / "benchmarks" / "kf_paths.py"
)
kp = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("kf_paths", kp)  # the name numba's cache of its kernels refers to
_spec.loader.exec_module(kp)


@pytest.fixture(autouse=True)
def _uncompiled():
    """The steps' Python, uncompiled: what numba compiles for the benchmark (compiling the three
    steps here would cost ~40 s of a cold test run; the compiled = uncompiled rule of navlab's own
    kernels is tests/unit/test_jit_kernels.py's).
    """
    with numpy_paths():
        yield


def _problem(B: int, n: int, m: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((B, n, n))
    P = A @ A.swapaxes(1, 2) + np.eye(n)
    x = rng.standard_normal((B, n))
    z = rng.standard_normal((B, m))
    z[1, 0] = np.nan  # a missing channel
    if B > 2:
        z[2, :] = np.nan  # every channel missing
    H = np.eye(n)[rng.choice(n, m, replace=False)]
    C = rng.standard_normal((m, m))
    R = C @ C.T + np.eye(m)  # correlated channels
    F = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    return x, P, z, H, R, F, np.eye(n) * 0.01


class _Model:
    def __init__(self, H, R):
        self.H_, self.R0 = H, R

    def H(self, x, k):
        return self.H_

    def h(self, x, k):
        return x @ self.H_.T


@pytest.mark.parametrize("step", ["textbook", "expanded", "loops"])
@pytest.mark.parametrize(("n", "m"), [(4, 2), (15, 3), (6, 4)])
def test_one_run_step_equals_the_batched_update(n, m, step):
    step, predict = kp.PATHS[step]
    x, P, z, H, R, F, Q = _problem(4, n, m)
    x1, P1 = predict((x, P), (F, Q))
    np.testing.assert_allclose(x1, x @ F.T, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(P1, predict_cov(F, P, Q), rtol=1e-12, atol=1e-12)
    mk = measurement_prediction(_Model(H, R), x1, P1, 0, z, R, H)
    xb, Pb, Sb, _, fixed_b = kf_update(x1, P1, mk.U, mk.M, mk.nu, mk.R)
    nu = z - x1 @ H.T
    B = x.shape[0]
    xc, Pc, nuc, Sc, Rc, fixed_c = step((x1, P1, nu, np.ones((B, m)), np.tile(R, (B, 1, 1))), (H,))
    np.testing.assert_allclose(xc, xb, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(Pc, Pb, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(Sc, Sb, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(nuc, mk.nu)
    np.testing.assert_array_equal(Rc, mk.R)
    assert not fixed_c.any() and not np.any(fixed_b)
    np.testing.assert_array_equal(xc[2], x1[2])  # no channel: x⁺ = x⁻


@pytest.mark.parametrize("step", ["textbook", "expanded", "loops"])
def test_rejected_channel_gets_a_zero_gain_column_as_in_the_batched_gain(step):
    x, P, z, H, R, _, _ = _problem(2, 4, 2)
    w = np.array([[1.0, 0.0], [1.0, 1.0]])
    mk = measurement_prediction(_Model(H, R), x, P, 0, z, R, H)
    S = sym(mk.M + mk.R)
    K, _ = kf_gain(mk.U, S)
    K = zero_columns(K, w == 0)  # KalmanUpdate.gain
    xb, Pb = x + mv(K, mk.nu), joseph_from_gain(P, K, mk.U, S)
    xc, Pc, *_ = kp.PATHS[step][0]((x, P, z - x @ H.T, w, np.tile(R, (2, 1, 1))), (H,))
    np.testing.assert_allclose(xc, xb, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(Pc, Pb, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize(
    ("scenario", "key"), [("cv2d", "kf"), ("cv2d", "hakf"), ("sins-gps", "kf"), ("sins-gps", "huber-kf")]
)
@pytest.mark.parametrize("step", ["textbook", "expanded", "loops"])
def test_filters_with_the_one_run_step_give_the_same_numbers(scenario, key, step):
    p = plan(ExperimentSpec(scenario=scenario, filters=(key,), runs=3, epochs=12))
    data = p.scenario.simulate(p.schedule, p.outliers, range(3), 1)
    z = data.z.copy()
    z[1, 3:6, 0] = np.nan  # a missing channel in one run
    z[2, 7, :] = np.nan  # an epoch without measurements

    def run():
        f = make_filter(key, p.scenario.filter_defaults.get(key, {}))
        st, xs, Ps = f.init(data.model, data.x0, data.P0), [], []
        for k in range(1, data.K + 1):
            st = f.predict(data.model, st, k)
            st, out = f.update(data.model, st, k, z[:, k], data.side(k))
            xs.append(out.x)
            Ps.append(np.broadcast_to(out.P, (3, *out.P.shape[-2:])))
        return np.array(xs), np.array(Ps)

    xb, Pb = run()
    with kp.compiled_kf(*kp.PATHS[step]):
        xc, Pc = run()
    scale = np.sqrt(np.diagonal(Pb, axis1=-2, axis2=-1))  # compare in units of each state's σ
    assert np.max(np.abs(xc - xb) / scale[..., :]) < 1e-8
    assert np.max(np.abs(Pc - Pb) / (scale[..., :, None] * scale[..., None, :])) < 1e-8
