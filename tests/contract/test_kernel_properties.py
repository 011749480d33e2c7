"""The small-matrix kernels (navlab/linalg.py and the VB step) against the textbook formulas,
with hypothesis over the batch size B, the state and measurement dimensions n, m, shared or
per-run operands, and missing-channel (NaN) patterns. Matrices are drawn by a seeded numpy
Generator whose seed hypothesis chooses (so every failure replays).
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from navlab.filters.huber_vb import measurement_space_update
from navlab.filters.kalman import kf_update
from navlab.linalg import (
    PHt,
    batched,
    bcast,
    cofactors,
    inv_small,
    inv_spd,
    joseph_from_gain,
    kf_gain,
    mask_missing,
    predict_cov,
    quad,
    selection,
)

FAST = settings(max_examples=40, deadline=None)
dims = st.integers(1, 6)
seeds = st.integers(0, 2**32 - 1)


def spd(rng, shape, m, cond=1e3):
    """Random SPD matrices (*shape, m, m) with condition number up to ``cond``."""
    A = rng.standard_normal((*shape, m, m))
    Q, _ = np.linalg.qr(A)
    w = np.exp(rng.uniform(0, np.log(cond), (*shape, m)))
    S = (Q * w[..., None, :]) @ np.swapaxes(Q, -1, -2)
    return 0.5 * (S + np.swapaxes(S, -1, -2))


@FAST
@given(B=st.integers(1, 6), m=dims, n=dims, shared=st.booleans(), seed=seeds)
def test_kf_gain_is_U_S_inverse(B, m, n, shared, seed):
    rng = np.random.default_rng(seed)
    S = spd(rng, () if shared else (B,), m)
    U = rng.standard_normal((B, n, m))
    K, fixed = kf_gain(U, S)
    np.testing.assert_allclose(K, U @ np.linalg.inv(S), rtol=1e-8, atol=1e-10 * np.abs(U).max())
    assert not np.any(fixed)


@FAST
@given(B=st.integers(1, 6), m=st.integers(1, 5), seed=seeds)
def test_inverse_and_cofactors(B, m, seed):
    rng = np.random.default_rng(seed)
    S = spd(rng, (B,), m)
    ref = np.linalg.inv(S)
    Si, fixed = inv_spd(S)
    np.testing.assert_allclose(Si, ref, rtol=1e-8, atol=1e-10 * np.abs(ref).max())
    assert not fixed.any()
    if m <= 3:
        inv, _ill = inv_small(S)
        np.testing.assert_allclose(inv, ref, rtol=1e-8, atol=1e-10 * np.abs(ref).max())
        C = cofactors(S.reshape(B, m * m), m).reshape(B, m, m)
        np.testing.assert_allclose(C, ref * np.linalg.det(S)[:, None, None], rtol=1e-8, atol=1e-8)


@FAST
@given(
    d=st.integers(1, 12),
    N=st.sampled_from([1, 5, 600]),
    layout=st.sampled_from(["batched", "shared", "broadcast", "stacked"]),
    seed=seeds,
)
def test_quad_is_the_quadratic_form(d, N, layout, seed):
    """vᵀ S⁻¹ v through every branch of the dispatcher (closed form, LU, LDLᵀ, Cholesky, shared)."""
    rng = np.random.default_rng(seed)
    if layout == "stacked":  # (L, B, d) with S constant along the runs (the recorder's shared P)
        v = rng.standard_normal((3, N, d))
        S = np.broadcast_to(spd(rng, (3,), d)[:, None], (3, N, d, d))
    else:
        v = rng.standard_normal((N, d))
        S = {
            "batched": lambda: spd(rng, (N,), d),
            "shared": lambda: spd(rng, (), d),
            "broadcast": lambda: np.broadcast_to(spd(rng, (), d), (N, d, d)),
        }[layout]()
    Sb = np.broadcast_to(S, (*v.shape, d))
    ref = np.einsum("...i,...i->...", v, np.linalg.solve(Sb, v[..., None])[..., 0])
    np.testing.assert_allclose(quad(v, S), ref, rtol=1e-7)


@FAST
@given(d=st.integers(1, 10), N=st.integers(2, 40), shared=st.booleans(), seed=seeds)
def test_quad_of_a_run_does_not_depend_on_its_batch(d, N, shared, seed):
    """Bit for bit: a run's NIS/NEES is the same alone and in any chunk (the recorder relies on it)."""
    rng = np.random.default_rng(seed)
    v = rng.standard_normal((N, d))
    S = np.broadcast_to(spd(rng, (), d), (N, d, d)) if shared else spd(rng, (N,), d)
    q = quad(v, S)
    for i in (0, N // 2, N - 1):
        assert quad(v[i : i + 1], S[i : i + 1])[0] == q[i]
        assert quad(v[: i + 1], S[: i + 1])[i] == q[i]


def test_quad_is_nan_only_where_S_is_singular():
    S = np.broadcast_to(np.eye(3), (700, 3, 3)).copy()
    S[4] = 0.0
    S[6] = np.diag([-1.0, 2.0, 3.0])  # indefinite but invertible: still the quadratic form
    q = quad(np.ones((700, 3)), S)
    assert np.isnan(q[4]) and np.isfinite(np.delete(q, 4)).all()
    assert q[6] == -1 + 0.5 + 1 / 3


@FAST
@given(
    B=st.integers(1, 5),
    n=dims,
    m=dims,
    H_kind=st.sampled_from(["selection", "general"]),
    P_shared=st.booleans(),
    seed=seeds,
)
def test_PHt_and_predict_cov(B, n, m, H_kind, P_shared, seed):
    rng = np.random.default_rng(seed)
    H = np.eye(n)[rng.integers(0, n, m)] if H_kind == "selection" else rng.standard_normal((m, n))
    P = spd(rng, () if P_shared else (B,), n)
    U, M = PHt(P, H)
    np.testing.assert_allclose(U, P @ H.T, rtol=1e-12, atol=1e-12 * np.abs(P).max())
    np.testing.assert_allclose(M, H @ P @ H.T, rtol=1e-10, atol=1e-10 * np.abs(P).max() * n)
    assert (selection(H) is not None) == (H_kind == "selection" or bool(np.all(np.isin(H, (0.0, 1.0)))))
    F, Q = rng.standard_normal((n, n)), spd(rng, (), n)
    ref = F @ P @ F.T + Q
    np.testing.assert_allclose(
        predict_cov(F, P, Q), 0.5 * (ref + np.swapaxes(ref, -1, -2)), rtol=1e-9, atol=1e-9
    )


@FAST
@given(B=st.integers(1, 5), n=dims, m=dims, seed=seeds)
def test_joseph_from_gain_is_the_joseph_form_for_any_gain(B, n, m, seed):
    rng = np.random.default_rng(seed)
    P, R = spd(rng, (B,), n), spd(rng, (), m)
    H = rng.standard_normal((m, n))
    K = rng.standard_normal((B, n, m))  # not the optimal gain
    IKH = np.eye(n) - K @ H
    ref = IKH @ P @ np.swapaxes(IKH, -1, -2) + K @ R @ np.swapaxes(K, -1, -2)
    got = joseph_from_gain(P, K, P @ H.T, H @ P @ H.T + R)
    np.testing.assert_allclose(got, ref, rtol=1e-8, atol=1e-8 * np.abs(ref).max())


@FAST
@given(B=st.integers(1, 5), n=dims, m=st.integers(2, 6), mask=st.integers(0, 2**30), seed=seeds)
def test_missing_channels_get_a_zero_gain_column(B, n, m, mask, seed):
    """The masked KF update (linalg.mask_missing + kalman.kf_update) equals, run by run, the
    textbook update with the missing channels deleted; a run with none present is unchanged.
    """
    rng = np.random.default_rng(seed)
    P, R = spd(rng, (), n), spd(rng, (), m)
    H = rng.standard_normal((m, n))
    x = rng.standard_normal((B, n))
    z = rng.standard_normal((B, m))
    bits = (mask >> np.arange(B * m)) & 1
    z[bits.reshape(B, m).astype(bool)] = np.nan
    nu = z - x @ H.T
    U, M = PHt(P, H)
    mk = mask_missing(z, nu, R, U=U, M=M, H=H)
    x1, P1, *_ = kf_update(x, P, mk.U, mk.M, mk.nu, mk.R)
    P1 = np.broadcast_to(P1, (B, n, n))
    for b in range(B):
        o = np.flatnonzero(np.isfinite(z[b]))
        if o.size == 0:
            np.testing.assert_allclose(x1[b], x[b], rtol=0, atol=0)
            np.testing.assert_allclose(P1[b], P, rtol=1e-12, atol=1e-12)
            continue
        Ho, Ro = H[o], R[np.ix_(o, o)]
        K = P @ Ho.T @ np.linalg.inv(Ho @ P @ Ho.T + Ro)
        np.testing.assert_allclose(x1[b], x[b] + K @ nu[b, o], rtol=1e-8, atol=1e-8)
        IKH = np.eye(n) - K @ Ho
        np.testing.assert_allclose(P1[b], IKH @ P @ IKH.T + K @ Ro @ K.T, rtol=1e-8, atol=1e-8)
    assert np.all(mk.nu[~mk.ok] == 0) and np.all(np.broadcast_to(mk.H, (B, m, n))[~mk.ok] == 0)


@FAST
@given(B=st.integers(1, 6), m=st.integers(1, 5), seed=seeds)
def test_vb_measurement_space_update_equals_state_space(B, m, seed):
    """The one-run VB update in measurement space equals the state-space update x⁺ = x⁻ + K ν,
    P⁺ = (I − K H) P⁻ projected (S0 eqs. 18–20), run by run (the step uncompiled).
    """
    rng = np.random.default_rng(seed)
    n = m + 2
    H = rng.standard_normal((m, n))
    P = spd(rng, (B,), n)
    M = H @ P @ H.T
    nu = rng.standard_normal((B, m))
    Rt = rng.uniform(0.1, 5.0, (B, m))
    K = P @ H.T @ np.linalg.inv(M + Rt[:, :, None] * np.eye(m))
    dx = (K @ nu[..., None])[..., 0]
    Pp = P - K @ H @ P
    for b in range(B):
        work = np.empty((3, m, m))
        resid, hph = np.empty(m), np.empty(m)
        fixed = measurement_space_update(M[b], nu[b], Rt[b], *work, resid, hph)
        np.testing.assert_allclose(resid, nu[b] - H @ dx[b], rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(hph, np.diag(H @ Pp[b] @ H.T), rtol=1e-7, atol=1e-8 * np.abs(M).max())
        assert not fixed


@FAST
@given(B=st.sampled_from([1, 3, 120]), p=dims, n=st.integers(1, 16), q=dims, seed=seeds)
def test_broadcast_views(B, p, n, q, seed):
    """The broadcast views."""
    rng = np.random.default_rng(seed)
    M, A = rng.standard_normal((p, n)), rng.standard_normal((B, n, q))
    v = bcast(M, (B, p, n))
    assert v.shape == (B, p, n) and not v.flags.writeable and np.array_equal(v[-1], M)
    assert batched(M, B).shape == (B, p, n) and batched(A, B) is A
