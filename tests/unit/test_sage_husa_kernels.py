"""The one-run R̂ steps of navlab/filters/sage_husa/kernels.py against straightforward references.

The filters' end-to-end outputs are pinned in test_linear_pinned.py and compiled = uncompiled in
test_jit_kernels.py; these tests aim at the edge cases (eigenvalues at the clamp bounds, NaN runs,
missing channels in the residual window, k1 < k0).
"""

from __future__ import annotations

import numpy as np
import pytest

from navlab import jit
from navlab.filters.sage_husa import clamp_to_band, igg3_weights, irakf_weights, rae_rhat
from navlab.filters.sage_husa.kernels import CLAMP_TO_BAND
from navlab.linalg import eigh_clamp, sym


def _random_sym(rng, B, m, scale=1.0):
    A = rng.standard_normal((B, m, m)) * scale
    return sym(A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(m))


def _clamp_reference(R, lo, hi):
    """eigh on every finite run; a variance 'changed' where the clamp moved it by > 1e-9."""
    good = np.all(np.isfinite(R), axis=(-2, -1))
    out = np.full(R.shape, np.nan)
    out[good], _ = eigh_clamp(R[good], lo, hi)
    d0, d1 = np.diagonal(R, axis1=-2, axis2=-1), np.diagonal(out, axis1=-2, axis2=-1)
    with np.errstate(invalid="ignore"):
        changed = ~good[:, None] | (np.abs(d1 - d0) > 1e-9 * np.maximum(np.abs(d0), lo))
    return out, changed


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("m", [1, 2, 3, 4])
def test_clamp_equals_eigh_everywhere(m, compiled):
    if compiled and not jit.enabled():
        pytest.skip("numba not available")
    fn = CLAMP_TO_BAND.get() if compiled else clamp_to_band
    s0 = 0.7  # R0 = s0 I: the band [lo, hi] × R0 is [lo s0, hi s0] on the eigenvalues

    def clamp(R, lo, hi):
        return fn(R, s0 * np.eye(m), np.sqrt(s0) * np.eye(m), lo / s0, hi / s0)

    rng = np.random.default_rng(m)
    R = _random_sym(rng, 400, m)
    lo, hi = 0.3, 6.0  # many runs outside on either side, many inside
    w = np.linalg.eigvalsh(R)
    assert (w.min(-1) < lo).any() and (w.max(-1) > hi).any()
    assert ((w.min(-1) > lo) & (w.max(-1) < hi)).any()
    # eigenvalues exactly at a bound, and a NaN run
    V = np.linalg.qr(rng.standard_normal((m, m)))[0]
    R[0] = V @ np.diag(np.r_[lo, np.full(m - 1, 1.0)]) @ V.T
    R[1] = V @ np.diag(np.r_[hi, np.full(m - 1, 1.0)]) @ V.T
    R[2, 0, 0] = np.nan
    runs = [clamp(np.ascontiguousarray(Rr), lo, hi) for Rr in R]
    out, changed = np.stack([r[0] for r in runs]), np.stack([r[1] for r in runs])
    ref, ref_changed = _clamp_reference(R, lo, hi)
    np.testing.assert_array_equal(changed, ref_changed)
    np.testing.assert_array_equal(np.isnan(out), np.isnan(ref))
    np.testing.assert_allclose(out[3:], ref[3:], rtol=1e-12, atol=1e-12 * hi)


def test_rae_with_missing_channels_stays_psd_and_falls_back_to_r0():
    eta = np.array([[1.0, 2.0], [3.0, 0.0]])
    ok = np.array([[True, True], [True, False]])
    r0 = np.array([4.0, 9.0])
    band = (np.diag(r0), np.diag(np.sqrt(r0)), 1e-6, 1e6)
    R = rae_rhat(eta, ok, np.zeros((2, 2)), *band)[0]
    assert R[0, 0] == pytest.approx((1 + 9) / 2)
    assert R[1, 1] == pytest.approx(4.0)  # only one epoch with channel 1
    assert R[0, 1] == pytest.approx(2.0 / np.sqrt(2.0))  # D Σηηᵀ D, D = diag(1/√c_i): PSD
    assert np.linalg.eigvalsh(R).min() >= 0
    R = rae_rhat(eta, np.zeros_like(ok), np.zeros((2, 2)), *band)[0]
    np.testing.assert_allclose(R, np.diag(r0))  # a channel never present: R0_ii


def _weights_reference(a, k0, k1, mid):
    zone = np.where(a > k1, 2, np.where(a > k0, 1, 0)).astype(np.int8)
    return np.where(zone == 0, 1.0, np.where(zone == 1, mid, 0.0)), zone


@pytest.mark.parametrize(("k0", "k1"), [(1.5, 3.0), (1.5, 1.5), (0.0, 3.0), (2.0, 1.0)])
def test_weight_functions_match_their_three_segment_definitions(k0, k1):
    rng = np.random.default_rng(3)
    nt = rng.standard_normal((500, 2)) * 3
    nt[0] = [np.nan, 0.0]
    nt[1] = [k0, -k1]  # exactly at the thresholds
    a = np.abs(nt)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        huber = k0 / np.where(a > 0, a, 1.0)
        igg = huber * ((k1 - a) / max(k1 - k0, 1e-300)) ** 2
    for got, ref in (
        (irakf_weights(nt, k0, k1), _weights_reference(a, k0, k1, huber)),
        (igg3_weights(nt, k0, k1), _weights_reference(a, k0, k1, igg)),
    ):
        np.testing.assert_array_equal(got[1], ref[1])
        assert got[1].dtype == np.int8
        np.testing.assert_array_equal(got[0], ref[0])


def test_band_is_relative_to_the_nominal_r0():
    """With unequal nominal variances each channel's band is its own: [r_min, r_max] × R0_ii."""
    R0 = np.diag([1.0, 100.0])
    L0 = np.sqrt(R0)
    R, changed = clamp_to_band(np.diag([0.5, 0.5]), R0, L0, 0.25, 16.0)
    np.testing.assert_allclose(np.diag(R), [0.5, 25.0])  # channel 1 raised to 0.25 × 100
    np.testing.assert_array_equal(changed, [False, True])
    R, changed = clamp_to_band(np.diag([20.0, 50.0]), R0, L0, 0.25, 16.0)
    np.testing.assert_allclose(np.diag(R), [16.0, 50.0])
    np.testing.assert_array_equal(changed, [True, False])
    # correlated R0: the band is on the eigenvalues of L0⁻¹ R̂ L0⁻ᵀ, so R̂ = c R0 is kept as it is
    R0 = np.array([[4.0, 1.8], [1.8, 1.0]])
    L0 = np.linalg.cholesky(R0)
    R, changed = clamp_to_band(3.0 * R0, R0, L0, 0.25, 16.0)
    np.testing.assert_allclose(R, 3.0 * R0)
    assert not changed.any()
    R, _ = clamp_to_band(0.01 * R0, R0, L0, 0.25, 16.0)
    np.testing.assert_allclose(R, 0.25 * R0)
