"""Compiled kernels (navlab.jit) against their numpy reference paths, and navlab without numba."""

import contextlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from navlab import jit
from navlab.ins import init_state, propagate_block
from navlab.ins.earth import dcm_to_rotvec, orthonormalize, rotvec_to_dcm
from navlab.warmup import warm

ROOT = Path(__file__).resolve().parents[2]

needs_numba = pytest.mark.skipif(not jit.enabled(), reason="numba not available")


def _states(B, rng):
    return init_state(
        np.radians(40.0) + 1e-3 * rng.standard_normal(B),
        np.radians(-105.0) + 1e-3 * rng.standard_normal(B),
        1600.0 + rng.standard_normal(B),
        10.0 * rng.standard_normal((B, 3)),
        rotvec_to_dcm(rng.standard_normal((B, 3))),
        bias_g_radps=1e-4 * rng.standard_normal((B, 3)),
        bias_a_mps2=1e-2 * rng.standard_normal((B, 3)),
        t_s=0.0,
    )


def _block(rng, N, per_run_B=None):
    shape = (N, 3) if per_run_B is None else (per_run_B, N, 3)
    f = np.array([0.3, -0.2, 9.8]) + 0.5 * rng.standard_normal(shape)
    w = 0.3 * rng.standard_normal(shape)
    w[..., N // 2, :] = [30.0, -5.0, 2.0]  # one large rotation (not the small-angle series)
    t = np.sort(0.01 * np.arange(N) + 1e-3 * rng.random(N))
    t[3] = t[2]  # a zero-length sample: skipped
    return t, f, w


@needs_numba
@pytest.mark.parametrize("per_run", [False, True])
@pytest.mark.parametrize("reorth", [True, False])
def test_compiled_mechanisation_equals_the_numpy_reference(per_run, reorth):
    rng = np.random.default_rng(1)
    B, N = 6, 150
    s0 = _states(B, rng)
    t, f, w = _block(rng, N, B if per_run else None)
    fast, fb = propagate_block(s0, t, f, w, t_end_s=t[-1] + 0.01, reorthonormalise=reorth)
    with jit.numpy_paths():
        ref, rb = propagate_block(s0, t, f, w, t_end_s=t[-1] + 0.01, reorthonormalise=reorth)
    for name, tol in (
        ("lat_rad", 1e-15),
        ("lon_rad", 1e-15),
        ("h_m", 1e-12),
        ("v_enu_mps", 1e-12),
        ("C_bn", 1e-14),
    ):
        np.testing.assert_allclose(getattr(fast, name), getattr(ref, name), rtol=0, atol=tol, err_msg=name)
    for name in ("f_b_mean_mps2", "w_b_mean_radps", "f_n_mean_mps2"):
        np.testing.assert_allclose(getattr(fb, name), getattr(rb, name), rtol=0, atol=1e-13, err_msg=name)
    assert fb.dt_s == rb.dt_s and fb.n_samples == rb.n_samples
    assert fast.t_s == ref.t_s
    # the input state is not modified in place
    np.testing.assert_array_equal(s0.C_bn, _states(B, np.random.default_rng(1)).C_bn)
    orth = np.swapaxes(fast.C_bn, -1, -2) @ fast.C_bn - np.eye(3)
    if reorth:
        assert np.abs(orth).max() < 1e-15


@needs_numba
def test_compiled_reorthonormalisation_is_the_polar_factor():
    rng = np.random.default_rng(2)
    C = rotvec_to_dcm(rng.standard_normal((5, 3))) + 1e-9 * rng.standard_normal((5, 3, 3))
    s = init_state(0.7, -1.9, 1600.0, np.zeros(3), C)
    out, _ = propagate_block(s, np.array([0.0]), np.zeros((1, 3)), np.zeros((1, 3)), t_end_s=0.0)
    np.testing.assert_allclose(out.C_bn, orthonormalize(C), rtol=0, atol=1e-14)  # a few ulps


@needs_numba
def test_compiled_rotation_conversions_equal_the_numpy_reference():
    rng = np.random.default_rng(3)
    for scale in (0.0, 1e-10, 1e-4, 0.5, 3.0):
        phi = scale * rng.standard_normal((4, 2, 3))
        C = rotvec_to_dcm(phi)
        back = dcm_to_rotvec(C)
        with jit.numpy_paths():
            C_ref, back_ref = rotvec_to_dcm(phi), dcm_to_rotvec(C)
        assert C.shape == (4, 2, 3, 3) and back.shape == (4, 2, 3)
        np.testing.assert_allclose(C, C_ref, rtol=0, atol=1e-15)
        np.testing.assert_allclose(back, back_ref, rtol=0, atol=1e-14)
        if scale < 1.0:  # |φ| < π: the rotation vector comes back
            np.testing.assert_allclose(back, phi, rtol=0, atol=1e-12)
    assert rotvec_to_dcm([0.0, 0.0, 0.1]).shape == (3, 3)
    assert dcm_to_rotvec(np.eye(3)).shape == (3,)


def _python(code: str, *args: str, **env: str) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter from the checkout (NAVLAB_NUMBA from ``env`` only)."""
    base = {k: v for k, v in os.environ.items() if k != "NAVLAB_NUMBA"}
    return subprocess.run(
        [sys.executable, "-c", code, *args],
        cwd=ROOT,
        env={**base, **env},
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


def test_an_unknown_navlab_numba_value_is_named():
    """NAVLAB_NUMBA=abc is neither off nor on: a warning says the kernels stay on (no silent guess)."""
    out = _python("from navlab import jit; print(jit._OFF)", NAVLAB_NUMBA="abc")
    assert out.returncode == 0 and out.stdout.strip() == "False"
    assert "NAVLAB_NUMBA='abc' is neither 0/off nor 1/on" in out.stderr
    quiet = _python("from navlab import jit; print(jit._OFF)", NAVLAB_NUMBA="off")
    assert quiet.stdout.strip() == "True" and "NAVLAB_NUMBA" not in quiet.stderr


@pytest.mark.slow
def test_navlab_runs_without_numba():
    """With numba unimportable, navlab runs its numpy paths (a broken or missing install)."""
    code = (
        "import sys; sys.modules['numba'] = None\n"  # import numba -> ImportError
        "from navlab import jit\n"
        "from navlab.experiment import ExperimentSpec, run_experiment\n"
        "from navlab.warmup import warm\n"
        "assert not jit.enabled() and warm() == {}\n"
        "res = run_experiment(ExperimentSpec(filters=('kf',), runs=70, epochs=20))\n"
        "assert res.data.B == 70\n"
        "print('ok')\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "NAVLAB_NUMBA"}
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


@pytest.mark.slow
@needs_numba
def test_without_numba_the_numbers_are_the_same_to_round_off(tmp_path):
    """NAVLAB_NUMBA=0 (numpy paths) and the compiled paths give one experiment's numbers."""
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from navlab.experiment import ExperimentSpec, run_experiment\n"
        "res = run_experiment(ExperimentSpec(scenario='sins-gps', filters=('kf',), runs=3, epochs=40))\n"
        "np.save(sys.argv[1], np.concatenate([res.data.x_true.ravel(), res.runs['kf'].x.ravel()]))\n"
    )
    outs = []
    for flag, name in (("0", "numpy"), ("1", "compiled")):
        path = tmp_path / f"{name}.npy"
        proc = _python(code, str(path), NAVLAB_NUMBA=flag)
        assert proc.returncode == 0, proc.stderr
        outs.append(np.load(path))
    np.testing.assert_allclose(outs[0], outs[1], rtol=1e-12, atol=1e-12 * np.abs(outs[0]).max())


def test_warm_compiles_every_kernel():
    took = warm()
    if not jit.enabled():
        assert took == {}
        return
    assert set(took) == {
        "strapdown.propagate_block",
        "scenarios.base.propagate",
        "earth rotation conversions",
        "filter kernels (solve, quadratic form, Joseph, VB, Sage–Husa, UKF steps, RBF clustering)",
        "ins.lc model f, h, H",
    }
    # every kernel of the filters and the INS model is compiled (one signature each)
    from navlab import linalg
    from navlab.filters import huber_vb, rbf
    from navlab.filters.sage_husa import kernels, rakf
    from navlab.ins import lc

    for k in (
        linalg._SOLVE,
        linalg._QUAD,
        linalg._JOSEPH,
        huber_vb.VB_ITERATIONS,
        huber_vb.STUDENT_T_ITERATIONS,
        kernels.SAGE_HUSA_RHAT,
        kernels.RAE_RHAT,
        rakf.RAKF_STEP,
        lc._F_RUNS,
        lc._HH_RUNS,
        rbf.CLUSTER,
    ):
        assert len(k.get().signatures) == 1, k.fn.__name__  # a RunStep: its compiled loop


@needs_numba
def test_one_compiled_signature_per_kernel_whatever_the_arguments():
    """Read-only, strided or integer inputs must not compile another specialisation (seconds)."""
    from navlab.ins import earth

    phi = np.broadcast_to(np.array([0.1, 0.2, 0.3]), (4, 3))  # read-only view
    C = earth.rotvec_to_dcm(phi)
    earth.rotvec_to_dcm(np.zeros((3, 6))[:, ::2])  # strided
    earth.rotvec_to_dcm(np.array([[1, 0, 0]]))  # integers
    earth.dcm_to_rotvec(np.broadcast_to(C[0], (2, 3, 3)))
    assert len(earth._ROTVEC_TO_DCM.get().signatures) == 1
    assert len(earth._DCM_TO_ROTVEC.get().signatures) == 1


@needs_numba
def test_one_compiled_signature_per_run_step_whatever_the_shared_parameters():
    """A read-only or numpy-typed shared parameter (the diag R0 of a one-channel model is a
    read-only view) must not compile another specialisation of a RunStep's loop."""

    def scaled(x, a, s):  # pragma: no cover - compiled by numba
        return (x * a * s[0],)

    step = jit.RunStep(scaled, n_runs=1, outs=((0, float),))
    x = np.ones((3, 2))
    s = np.diagonal(np.eye(1))  # a read-only view
    assert not s.flags.writeable
    outs = [step((x,), (2.0, np.array([3.0])))[0], step((x,), (np.float64(2.0), s * 3))[0]]
    outs.append(step((x,), (2.0, np.broadcast_to(3.0, (1,))))[0])
    for out in outs:
        np.testing.assert_array_equal(out, 6.0)
    assert len(step.get().signatures) == 1


def test_run_step_result_shaped_by_a_function_of_the_run_arguments():
    """``outs`` may give a result's one-run shape as a function of the run arguments' one-run
    shapes (the UKF's sigma points (2n+1, n) of a mean (n,)); compiled and uncompiled alike."""

    def doubled(x, c):  # pragma: no cover - compiled by numba
        out = np.empty((2, x.shape[0]))
        out[0] = x
        out[1] = c * x
        return out, x.sum()

    step = jit.RunStep(doubled, n_runs=1, outs=((lambda x: (2, *x), float), (None, float)))
    x = np.arange(6.0).reshape(3, 2)
    for paths in (contextlib.nullcontext(), jit.numpy_paths()):
        with paths:
            out, s = step((x,), (3.0,))
        np.testing.assert_array_equal(out[:, 0], x)
        np.testing.assert_array_equal(out[:, 1], 3.0 * x)
        np.testing.assert_array_equal(s, x.sum(axis=1))
