"""The small-matrix kernels of navlab/linalg.py against LAPACK and the textbook formulas."""

from __future__ import annotations

import numpy as np
import pytest

from navlab.linalg import PHt, inv_small, joseph_from_gain, kf_gain, predict_cov, quad


def test_quad_matches_lapack_and_marks_singular_nan():
    rng = np.random.default_rng(0)
    for d in (1, 2, 4, 8, 12, 15):
        A = rng.standard_normal((30, 40, d, d))
        S = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(d)
        v = rng.standard_normal((30, 40, d))
        ref = np.einsum("lbi,lbi->lb", v, np.linalg.solve(S, v[..., None])[..., 0])
        np.testing.assert_allclose(quad(v, S), ref, rtol=1e-8)
    S = np.broadcast_to(np.eye(3), (30, 40, 3, 3)).copy()
    S[4, 5] = 0.0  # singular
    S[6, 7] = np.diag([-1.0, 2.0, 3.0])  # indefinite but invertible: still the quadratic form
    S[8, 9] = [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # zero pivot: LU decides
    q = quad(np.ones((30, 40, 3)), S)
    assert np.isnan(q[4, 5]) and q[6, 7] == pytest.approx(-1 + 0.5 + 1 / 3)
    assert q[8, 9] == pytest.approx(3.0)
    assert np.isfinite(np.delete(q.ravel(), 4 * 40 + 5)).all()
    S15 = np.broadcast_to(np.eye(15), (30, 40, 15, 15)).copy()
    S15[2, 3, 0, 0] = -1.0  # indefinite (Cholesky fails): LU gives the quadratic form
    S15[5, 6] = 0.0  # singular: NaN
    q = quad(np.ones((30, 40, 15)), S15)
    assert q[2, 3] == pytest.approx(13.0) and np.isnan(q[5, 6]) and q[0, 0] == pytest.approx(15)
    S2 = np.broadcast_to(np.eye(2), (30, 40, 2, 2)).copy()
    S2[1, 2] = [[1.0, 1.0], [1.0, 1.0]]  # singular 2×2 (the closed form's det = 0): NaN
    S2[3, 4] = [[0.0, 1.0], [1.0, 0.0]]  # indefinite: still the quadratic form
    q = quad(np.ones((30, 40, 2)) * [1.0, 2.0], S2)
    assert np.isnan(q[1, 2]) and q[3, 4] == pytest.approx(4.0) and q[0, 0] == pytest.approx(5.0)


def test_predict_cov_is_F_P_Ft_plus_Q():
    rng = np.random.default_rng(1)
    F, Q = rng.standard_normal((5, 5)), np.eye(5)
    A = rng.standard_normal((7, 5, 5))
    P = A @ np.swapaxes(A, -1, -2)
    np.testing.assert_allclose(predict_cov(F, P, Q), F @ P @ F.T + Q, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(predict_cov(F, P[0], Q), F @ P[0] @ F.T + Q, rtol=1e-12)


@pytest.mark.parametrize("Q_batched", [False, True])
def test_predict_cov_shared_F_path_equals_the_plain_products(Q_batched):
    """A shared F and stacked P (the one-GEMM path, here in several row pieces: 100 × 15 rows)
    give sym(F P Fᵀ + Q) to round-off, exactly symmetric, and leave the inputs alone.
    """
    rng = np.random.default_rng(3)
    B, n = 100, 15
    F = np.eye(n) + 0.1 * rng.standard_normal((n, n))
    A = rng.standard_normal((B, n, n))
    P = A @ np.swapaxes(A, -1, -2)
    Q = np.diag(rng.random(n)) if not Q_batched else np.eye(n) * rng.random((B, 1, 1))
    P0, Q0 = P.copy(), Q.copy()
    out = predict_cov(F, P, Q)
    ref = F @ P @ F.T + Q
    np.testing.assert_allclose(out, 0.5 * (ref + np.swapaxes(ref, -1, -2)), rtol=1e-12, atol=1e-12)
    assert np.array_equal(out, np.swapaxes(out, -1, -2))
    assert np.array_equal(P, P0) and np.array_equal(Q, Q0)


def test_small_matrix_kernels_equal_lapack():
    """The closed-form kernels the filters use for m ≤ 3 equal LAPACK's solutions."""
    rng = np.random.default_rng(2)
    for m in (1, 2, 3, 4):
        A = rng.standard_normal((50, m, m))
        S = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(m)
        U = rng.standard_normal((50, 5, m))
        v = rng.standard_normal((50, m))
        K, fixed = kf_gain(U, S)
        np.testing.assert_allclose(K, U @ np.linalg.inv(S), rtol=1e-9, atol=1e-12)
        assert not fixed.any()
        if m <= 3:  # the Joseph form from U = P Hᵀ and S = H P Hᵀ + R, for any gain
            H = rng.standard_normal((m, 5))
            P = rng.standard_normal((50, 5, 5))
            P = P @ np.swapaxes(P, -1, -2)
            R = S - H @ P @ H.T  # so that S = H P Hᵀ + R
            IKH = np.eye(5) - K @ H
            ref = IKH @ P @ np.swapaxes(IKH, -1, -2) + K @ R @ np.swapaxes(K, -1, -2)
            np.testing.assert_allclose(joseph_from_gain(P, K, P @ H.T, S), ref, atol=1e-9)
        ref = np.einsum("bi,bi->b", v, np.linalg.solve(S, v[..., None])[..., 0])
        np.testing.assert_allclose(quad(v, S), ref, rtol=1e-9)
        if m <= 3:
            inv, ill = inv_small(S)
            np.testing.assert_allclose(inv, np.linalg.inv(S), rtol=1e-9, atol=1e-12)
            assert not ill.any()
        K_ok = K
        S[3] = 0.0  # a singular S: the batch takes the LU path; only that run is jittered, flagged
        K, fixed = kf_gain(U, S)
        assert fixed.tolist() == [i == 3 for i in range(50)] and np.isfinite(K).all()
        np.testing.assert_allclose(np.delete(K, 3, 0), np.delete(K_ok, 3, 0), rtol=1e-8, atol=1e-10)
    H = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])  # a selection: indexing instead of products
    P = rng.standard_normal((6, 3, 3))
    U, HU = PHt(P, H)
    np.testing.assert_array_equal(U, P @ H.T)
    np.testing.assert_allclose(HU, H @ P @ H.T, rtol=1e-15)
    H = rng.standard_normal((2, 3))  # a general shared H: two GEMMs over the batch
    U, HU = PHt(P, H)
    np.testing.assert_allclose(U, P @ H.T, rtol=1e-12)
    np.testing.assert_allclose(HU, H @ P @ H.T, rtol=1e-12)


def test_selection_cache_is_safe_under_threads():
    """Many threads asking for more distinct H than the cache holds: right answers, no KeyError
    (the former dict cache could be cleared by one thread between another's check and read).
    """
    import threading

    from navlab.linalg import selection

    Hs = [np.eye(6)[[i % 6, (i + 1) % 6]] * (1.0 if i % 3 else 2.0) for i in range(300)]
    errors = []

    def work():
        try:
            for H in Hs:
                sel = selection(H)
                want = np.argmax(H, axis=1) if np.all(H.sum(axis=1) == 1.0) else None
                assert (sel is None and want is None) or np.array_equal(sel, want)
        except Exception as exc:  # pragma: no cover - the failure being tested for
            errors.append(exc)

    threads = [threading.Thread(target=work) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
