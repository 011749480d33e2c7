"""EKF: equals the KF on linear models, equals a plain textbook EKF on a nonlinear model, and the
pseudorange scenario's Jacobian matches finite differences."""

from dataclasses import dataclass

import numpy as np
import pytest
from linmodels import random_model, side

from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec, run_experiment
from navlab.filters import LinearModel, make_filter
from navlab.noise import make_outliers, make_schedule
from navlab.scenarios import make_scenario
from navlab.scenarios.gps_ins_pseudorange import SAT_AZ_EL_DEG, satellite_geometry


@pytest.mark.parametrize(("n", "m", "seed"), [(4, 2, 0), (3, 3, 1), (6, 1, 2), (8, 8, 3)])
def test_ekf_equals_kf_on_linear_models(n, m, seed):
    rng = np.random.default_rng(seed)
    F, Q, H, R = random_model(rng, n, m)
    model = LinearModel(F, Q, H, R)
    B = 5
    x0 = rng.standard_normal((B, n))
    P0 = np.diag(rng.uniform(0.5, 2.0, n))
    zs = rng.standard_normal((25, B, m)) * 3
    zs[3, 1, 0] = np.nan  # a missing channel too
    kf, ekf = make_filter("kf"), make_filter("ekf")
    s1, s2 = kf.init(model, x0, P0), ekf.init(model, x0, P0)
    for k, z in enumerate(zs, start=1):
        s1, o1 = kf.update(model, kf.predict(model, s1, k), k, z, side(B, m))
        s2, o2 = ekf.update(model, ekf.predict(model, s2, k), k, z, side(B, m))
        np.testing.assert_allclose(o2.x, o1.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(
            np.broadcast_to(o2.P, (B, n, n)), np.broadcast_to(o1.P, (B, n, n)), rtol=0, atol=1e-9
        )
        np.testing.assert_allclose(o2.innov, o1.innov, rtol=0, atol=1e-9)


@dataclass(frozen=True)
class RangeBearing:
    """A 4-state CV target seen by range and bearing from the origin; f nonlinear via F_at."""

    R0: np.ndarray
    n: int = 4
    m: int = 2
    linear: bool = False

    def F(self, k):
        raise AssertionError("the EKF must use F_at when the model has it")

    def F_at(self, x, k):
        # f(x) = [px + vx, py + vy, vx·c, vy·c] with c = 1 − 0.01·tanh(|v|²/100) (drag)
        v2 = x[:, 2] ** 2 + x[:, 3] ** 2
        c = 1 - 0.01 * np.tanh(v2 / 100)
        dc = -0.01 * (1 - np.tanh(v2 / 100) ** 2) / 100
        J = np.zeros((x.shape[0], 4, 4))
        J[:, 0, 0] = J[:, 1, 1] = 1
        J[:, 0, 2] = J[:, 1, 3] = 1
        J[:, 2, 2] = c + x[:, 2] * dc * 2 * x[:, 2]
        J[:, 2, 3] = x[:, 2] * dc * 2 * x[:, 3]
        J[:, 3, 2] = x[:, 3] * dc * 2 * x[:, 2]
        J[:, 3, 3] = c + x[:, 3] * dc * 2 * x[:, 3]
        return J

    def Q(self, k):
        return 0.01 * np.eye(4)

    def f(self, x, k):
        v2 = x[:, 2] ** 2 + x[:, 3] ** 2
        c = 1 - 0.01 * np.tanh(v2 / 100)
        return np.stack([x[:, 0] + x[:, 2], x[:, 1] + x[:, 3], x[:, 2] * c, x[:, 3] * c], axis=1)

    def h(self, x, k):
        return np.stack([np.hypot(x[:, 0], x[:, 1]), np.arctan2(x[:, 1], x[:, 0])], axis=1)

    def H(self, x, k):
        r2 = x[:, 0] ** 2 + x[:, 1] ** 2
        r = np.sqrt(r2)
        H = np.zeros((x.shape[0], 2, 4))
        H[:, 0, 0], H[:, 0, 1] = x[:, 0] / r, x[:, 1] / r
        H[:, 1, 0], H[:, 1, 1] = -x[:, 1] / r2, x[:, 0] / r2
        return H


def textbook_ekf(model, x, P, zs):
    """Plain single-run EKF (short-form P update is the same as Joseph for the optimal gain)."""
    out = []
    for k, z in enumerate(zs, start=1):
        A = model.F_at(x[None], k)[0]
        x = model.f(x[None], k)[0]
        P = A @ P @ A.T + model.Q(k)
        H = model.H(x[None], k)[0]
        S = H @ P @ H.T + model.R0
        K = P @ H.T @ np.linalg.inv(S)
        x = x + K @ (z - model.h(x[None], k)[0])
        P = (np.eye(4) - K @ H) @ P
        out.append((x, P))
    return out


def test_ekf_equals_textbook_ekf_on_nonlinear_model():
    rng = np.random.default_rng(7)
    model = RangeBearing(R0=np.diag([0.5**2, 0.01**2]))
    x_true = np.array([50.0, 20.0, 3.0, -1.0])
    zs = []
    for k in range(1, 21):
        x_true = model.f(x_true[None], k)[0] + rng.standard_normal(4) * 0.1
        zs.append(model.h(x_true[None], k)[0] + rng.standard_normal(2) * [0.5, 0.01])
    zs = np.array(zs)
    x0, P0 = np.array([48.0, 22.0, 2.0, 0.0]), np.diag([4.0, 4.0, 1.0, 1.0])
    ref = textbook_ekf(model, x0, P0, zs)
    ekf = make_filter("ekf")
    st = ekf.init(model, x0[None], P0)
    for k, z in enumerate(zs, start=1):
        st, out = ekf.update(model, ekf.predict(model, st, k), k, z[None], side(1, 2))
        np.testing.assert_allclose(out.x[0], ref[k - 1][0], rtol=0, atol=1e-8)
        np.testing.assert_allclose(out.P[0], ref[k - 1][1], rtol=0, atol=1e-8)


def _pseudorange_model():
    scen = make_scenario("gps-ins-pseudorange", {"epochs": 5})
    data = scen.simulate(make_schedule("constant"), make_outliers("none"), [0, 1], seed=3)
    return data


def test_pseudorange_jacobian_matches_finite_differences():
    model = _pseudorange_model().model
    rng = np.random.default_rng(0)
    x = rng.standard_normal((3, 8)) * [30, 30, 30, 1, 1, 1, 10, 1]
    x[:, 6] += 357.0
    H = model.H(x, 1)
    eps = 1e-2
    for i in range(8):
        dx = np.zeros(8)
        dx[i] = eps
        fd = (model.h(x + dx, 1) - model.h(x - dx, 1)) / (2 * eps)
        np.testing.assert_allclose(H[:, :, i], fd, rtol=0, atol=1e-7)
    # at δr = 0 the rows are the §8.4 LOS rows [u_N, u_E, u_U, 0, 0, 0, 1, 0]
    los, _, _ = satellite_geometry(SAT_AZ_EL_DEG)
    H0 = model.H(np.zeros((1, 8)), 1)[0]
    np.testing.assert_allclose(H0[:, :3], los[:, [1, 0, 2]], atol=1e-15)
    np.testing.assert_array_equal(H0[:, 6], 1.0)
    np.testing.assert_array_equal(H0[:, [3, 4, 5, 7]], 0.0)


def test_pseudorange_h_is_the_range_difference():
    """h_j = ‖d_j + δr‖ − ‖d_j‖ + c_b, and a displacement towards a satellite makes z_j positive."""
    model = _pseudorange_model().model
    x = np.zeros((1, 8))
    x[0, :3] = [12.0, -7.0, 3.0]  # δN, δE, δU
    x[0, 6] = 5.0
    dr = np.array([-7.0, 12.0, 3.0])  # ENU
    ref = np.linalg.norm(model.d + dr, axis=1) - np.linalg.norm(model.d, axis=1) + 5.0
    np.testing.assert_allclose(model.h(x, 1)[0], ref, rtol=0, atol=1e-6)
    los, _, _ = satellite_geometry(SAT_AZ_EL_DEG)
    toward = np.zeros((1, 8))
    toward[0, :3] = 10 * los[0, [1, 0, 2]]  # INS displaced 10 m towards satellite 1
    assert model.h(toward, 1)[0, 0] == pytest.approx(10.0, abs=1e-4)


def test_pseudorange_transition_has_the_mixed_order():
    model = _pseudorange_model().model
    F = model.F(1)
    np.testing.assert_array_equal(F[[0, 1, 2, 6], [4, 3, 5, 7]], 1.0)
    np.testing.assert_array_equal(F[[0, 1], [3, 4]], 0.0)
    np.testing.assert_allclose(model.Q(1), model.Q(1).T)
    assert np.all(np.linalg.eigvalsh(model.Q(1)) > 0)


def test_pseudorange_interference_and_schedules():
    scen = make_scenario("gps-ins-pseudorange")
    data = scen.simulate(make_schedule("constant"), make_outliers("none"), [0], seed=1)
    sig = np.sqrt(data.R_schedule)
    np.testing.assert_allclose(sig[0], 3.0, rtol=1e-6)  # nominal at the start …
    b100 = 0.5 * (np.tanh(50 / 5) - np.tanh(-50 / 5))
    np.testing.assert_allclose(sig[100, [1, 3, 6]], 3.0 * (1 + 9 * b100))  # … 10× at the peak
    np.testing.assert_allclose(sig[100, [0, 2, 4, 5, 7]], 3.0)
    np.testing.assert_allclose(data.R_true[0], data.R_schedule)  # no outliers: R_true = schedule
    # the foundation's schedule multiplies on top of the interference
    d2 = scen.simulate(make_schedule("constant", {"factor": 2.0}), make_outliers("none"), [0], 1)
    np.testing.assert_allclose(d2.R_schedule, 4 * data.R_schedule)
    with pytest.raises(NavlabError, match="interfered"):
        make_scenario("gps-ins-pseudorange", {"interfered": [9]}).simulate(
            make_schedule("constant"), make_outliers("none"), [0], 1
        )


def test_pseudorange_run_is_the_same_alone_or_in_a_batch():
    scen = make_scenario("gps-ins-pseudorange", {"epochs": 20})
    sched, outl = make_schedule("constant"), make_outliers("mixture", {"contamination": 0.1})
    both = scen.simulate(sched, outl, [0, 1, 2], seed=5)
    one = scen.simulate(sched, outl, [2], seed=5)
    np.testing.assert_array_equal(both.x_true[2], one.x_true[0])
    np.testing.assert_array_equal(both.z[2], one.z[0])


def test_ekf_is_consistent_on_the_pseudorange_model_without_interference():
    """Truth and filter model agree: with R0 right, the EKF's ANEES lies in the χ² band."""
    spec = ExperimentSpec(
        scenario="gps-ins-pseudorange",
        filters=("ekf",),
        runs=20,
        outliers="none",
        scenario_params={"interference": 1.0, "epochs": 100},
    )
    df = run_experiment(spec).metrics().set_index("metric").value
    assert 7.0 < df["anees"] < 9.0  # n = 8
    assert 7.0 < df["anis"] < 9.0  # m = 8
