"""The compiled filter kernels (navlab.jit) against their numpy reference paths, to round-off.

Kernels: linalg's Cholesky solve (solve_sym, kf_gain), Joseph form and quadratic form; the VB
iterations of vb-akf / hakf / student-t-kf (huber_vb.vb_iterations, one run, uncompiled
as the oracle); the one-run steps of the Sage–Husa family (sage_husa.kernels, RAKF's step), every
option; the one-run steps of the UKF family (ukf: sigma points, moments, update, χ² test, fading;
a linear model's closed form feeds the update steps, ``resample="reuse"`` and the nonlinear
pseudorange model take the sigma points), every option; the INS model's f, h, H (ins.lc, through
the drive0708 scenario).
Each is compared with ``jit.numpy_paths()`` on the same inputs.
"""

import numpy as np
import pytest

from navlab import jit, linalg
from navlab.data import data_root
from navlab.data.loaders import RTKX_DIR
from navlab.experiment import ExperimentSpec, run_experiment, run_filters
from navlab.filters import make_filter
from navlab.noise import make_outliers, make_schedule
from navlab.scenarios.base import make_scenario

needs_numba = pytest.mark.skipif(not jit.enabled(), reason="numba not available")
pytestmark = needs_numba

RTOL = 1e-9


def _spd(rng, B, m, cond=1e3):
    """B random symmetric positive-definite m×m matrices (exactly symmetric), condition ≈ cond."""
    Q, _ = np.linalg.qr(rng.standard_normal((B, m, m)))
    w = np.exp(rng.uniform(0.0, np.log(cond), (B, m)))
    S = (Q * w[:, None, :]) @ np.swapaxes(Q, -1, -2)
    return linalg.sym(S)


def _both(fn, *args):
    """fn(*args) compiled, then on the numpy paths."""
    fast = fn(*args)
    with jit.numpy_paths():
        ref = fn(*args)
    return fast, ref


def _close(a, b, rtol=RTOL):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    scale = max(np.nanmax(np.abs(b)), 1e-300) if b.size else 1.0
    np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * scale)


# ------------------------------------------------------------------------------ linalg
@pytest.mark.parametrize(
    ("S_batched", "Y_batched"), [(True, True), (True, False), (False, True), (False, False)]
)
@pytest.mark.parametrize("m", [1, 4, 7])
def test_compiled_solve_sym_equals_lu(S_batched, Y_batched, m):
    rng = np.random.default_rng(m)
    B, q = 6, 3
    S = _spd(rng, B, m) if S_batched else _spd(rng, 1, m)[0]
    Y = rng.standard_normal((B, m, q) if Y_batched else (m, q))
    (X, fx), (Xr, fr) = _both(linalg.solve_sym, S, Y)
    _close(X, Xr)
    np.testing.assert_array_equal(fx, fr)
    assert X.shape == Xr.shape and fx.shape == fr.shape


def test_compiled_solve_sym_falls_back_to_lu_where_cholesky_cannot():
    """Singular (jitter, flag 9), indefinite and not exactly symmetric S: the LU's numbers."""
    rng = np.random.default_rng(7)
    B, m = 5, 5
    S = _spd(rng, B, m)
    S[1] = 0.0  # singular: LU with jitter
    S[1, 0, 0] = 1.0
    S[2] = np.diag([1.0, -2.0, 3.0, 4.0, 5.0])  # indefinite, regular
    S[3, 0, 1] += 1e-3  # not symmetric
    Y = rng.standard_normal((B, m, 2))
    (X, fx), (Xr, fr) = _both(linalg.solve_sym, S, Y)
    np.testing.assert_array_equal(fx, fr)
    assert fx.any()  # the singular one needed jitter on both paths
    ok = ~fx
    _close(X[ok], Xr[ok])


@pytest.mark.parametrize("m", [2, 3, 5, 8])
def test_compiled_gain_and_joseph_equal_numpy(m):
    rng = np.random.default_rng(10 + m)
    B, n = 7, 9
    P = _spd(rng, B, n)
    H = rng.standard_normal((m, n))
    R = _spd(rng, B, m)
    U = P @ H.T
    S = linalg.sym(H @ U + R)
    (K, f), (Kr, fr) = _both(linalg.kf_gain, U, S)
    _close(K, Kr)
    np.testing.assert_array_equal(f, fr)
    for args in ((P, K, U, S), (P[0], K[0], U[0], S[0]), (P[0], K, U, S)):  # batched, shared, mixed
        out, ref = _both(linalg.joseph_from_gain, *args)
        _close(out, ref)
        np.testing.assert_array_equal(out, np.swapaxes(out, -1, -2))  # exactly symmetric


@pytest.mark.parametrize("d", [4, 6, 15])
def test_compiled_quad_equals_lu(d):
    rng = np.random.default_rng(d)
    B, N = 4, 3
    S = _spd(rng, B, d)
    v = rng.standard_normal((B, d))
    cases = [
        (v, S),  # one S per v
        (v, S[0]),  # one shared S
        (rng.standard_normal((B, N, d)), linalg.bcast(S[:, None], (B, N, d, d))),  # stride 0 along N
        (rng.standard_normal((N, B, d)), S),  # S broadcast over a leading axis
        (v, linalg.bcast(S[0], (B, d, d))),  # a shared P as the KF keeps it (stride 0)
        (rng.standard_normal((0, d)), S[0]),  # empty
    ]
    for vv, SS in cases:
        q, qr = _both(linalg.quad, vv, SS)
        _close(q, qr)


def test_compiled_quad_not_positive_definite_is_decided_by_lu():
    rng = np.random.default_rng(3)
    d = 5
    S = _spd(rng, 5, d)
    S[0] = 0.0  # singular: NaN
    S[1] = np.diag([1.0, -1.0, 2.0, 3.0, 4.0])  # indefinite: the LU's (negative or positive) value
    S[2, 0, 0] = np.nan  # not finite: NaN
    S[3, 1, 2] += 0.1  # not symmetric: the LU's value
    v = rng.standard_normal((5, d))
    v[4, 0] = np.nan  # a NaN innovation: NaN
    q, qr = _both(linalg.quad, v, S)
    np.testing.assert_array_equal(np.isnan(q), np.isnan(qr))
    assert np.isnan(q[[0, 2, 4]]).all()
    _close(q[[1, 3]], qr[[1, 3]])


# ------------------------------------------------------------------------------ whole filters
def _assert_runs_equal(fast, ref, rtol=RTOL):
    for name in ("x", "P_diag", "innov", "S_diag", "nis", "nees", "R_used", "R_hat", "weights"):
        a, b = getattr(fast, name), getattr(ref, name)
        if b is None:
            assert a is None, name
            continue
        fin = np.isfinite(b)
        np.testing.assert_array_equal(np.isfinite(a), fin, err_msg=name)
        _close(a[fin], b[fin], rtol)
    np.testing.assert_array_equal(fast.flags, ref.flags)
    np.testing.assert_array_equal(fast.diverged_at, ref.diverged_at)
    for k in ref.stats:
        _close(fast.stats[k], ref.stats[k], rtol)


VB_CASES = [
    ("vb-akf", {}),
    ("vb-akf", {"tol": 0.0}),
    ("vb-akf", {"adapt": False}),
    ("hakf", {}),
    ("hakf", {"tol": 0.0, "irls": True}),
    ("hakf", {"robust_beta": True, "gamma": 1.0}),
    ("student-t-kf", {}),
]


SAGE_HUSA_CASES = [
    ("sage-husa", {}),
    ("sage-husa", {"full": True}),
    ("irakf", {}),
    ("irakf", {"improved_rae": "always", "middle_zone": "variance"}),
    ("irakf", {"middle_segment": "literal", "skf_gated": True, "window": 3}),
    ("rrae", {"window": 4}),
    ("rrae", {"form": "literal_scaling"}),
    ("rakf", {"gamma_s": 1.0, "c": 1.0}),
    ("rsshakf", {}),
    ("rsshakf", {"exclude_outliers": True}),
]


NN_SMALL = {"train_start": 5, "train_end": 40, "min_pairs": 10, "j_min": 3, "j_max": 20}
UKF_CASES = [
    ("svd-ukf", {}),
    ("svd-ukf", {"resample": "reuse", "alpha_ut": 0.5, "kappa": 1.0}),
    ("mfukf", {}),
    ("mfukf", {"form": "literal", "per_channel_gate": 1.0}),
    ("mfukf", {"recompute_sigma": True, "resample": "reuse", "sqrt_method": "cholesky"}),
    ("nnmfukf", NN_SMALL),
    ("nnmfukf-guarded", {**NN_SMALL, "mode": "online", "retest_after_replace": True}),
]


@pytest.mark.parametrize(("key", "params"), VB_CASES + SAGE_HUSA_CASES + UKF_CASES)
def test_compiled_one_run_steps_equal_numpy(key, params):
    """cv2d with outliers and a missing channel: every output of the filter, both paths."""
    scen = make_scenario("cv2d", {"epochs": 80})
    data = scen.simulate(
        make_schedule("constant", {}),
        make_outliers("mixture", {"contamination": 0.2, "scale": 10.0}),
        [0, 1, 2],
        4,
    )
    data.z[:, 20:26, 1] = np.nan
    data.z[1, 40, :] = np.nan

    def run():
        return run_filters(data, [make_filter(key, params)])[key]

    fast, ref = _both(run)
    _assert_runs_equal(fast, ref)


@pytest.mark.parametrize(
    ("scenario", "filters"),
    [
        # m = 8; the UKF's SVD sigma points of a nonlinear h
        (
            "gps-ins-pseudorange",
            ("kf", "chi2-kf", "vb-akf", "hakf", "sage-husa", "irakf", "svd-ukf", "mfukf"),
        ),
        ("gps-ins-rtk", ("kf", "hakf", "sage-husa", "mfukf")),  # m = 6
    ],
)
def test_compiled_paths_give_the_numbers_of_the_numpy_paths(scenario, filters):
    spec = ExperimentSpec(scenario=scenario, filters=filters, runs=3, epochs=60)
    fast, ref = _both(run_experiment, spec)
    for key in filters:
        _assert_runs_equal(fast.runs[key], ref.runs[key])


needs_rtkx = pytest.mark.skipif(
    not (data_root() / RTKX_DIR).is_dir(), reason=f"real data not found: {data_root() / RTKX_DIR}"
)


@needs_rtkx
def test_compiled_ins_model_gives_the_numbers_of_the_numpy_path():
    """drive0708: the INS model's f, h, H (lever arm, NHC rows) compiled, in every filter family."""
    from navlab.ins.lc import InsGnssModel

    spec = ExperimentSpec(
        scenario="drive0708",
        filters=("kf", "ekf", "hakf", "sage-husa", "svd-ukf"),
        runs=2,
        epochs=40,
    )
    fast, ref = _both(run_experiment, spec)
    for key in spec.filters:
        # the closed loop feeds the state back through f over 40 epochs: 1e-8 (round-off growth)
        _assert_runs_equal(fast.runs[key], ref.runs[key], rtol=1e-8)
    model = fast.data.model
    assert isinstance(model, InsGnssModel) and model.nhc
    rng = np.random.default_rng(0)
    x = fast.runs["kf"].x[:, 10] + 0.01 * rng.standard_normal((2, 15))
    for lever in (None, np.array([0.3, -0.5, 1.2])):
        if lever is not None:  # drive0708 has none (own-drive's parameter): the model's rows with one
            model.lever_b, model._lever, model.has_lever = lever, lever, True
        for k in (1, 11, 30):
            for fn in (model.f, model.h, model.H):
                out, ref_out = _both(fn, x, k)
                _close(out, ref_out, 1e-12)
