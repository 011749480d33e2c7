"""navlab.diagnostics: explanations of known filter failures (issue #11 item 6), on real runs and on
constructed flag patterns at the thresholds."""

from __future__ import annotations

import dataclasses
from urllib.parse import parse_qs, urlparse

import numpy as np
import pytest

from navlab import diagnostics as D
from navlab.experiment import ExperimentSpec, run_experiment
from navlab.filters.base import NUMERICAL_FIX, R_HAT_AT_BAND, REJECTED, REPLACED


@pytest.fixture(scope="module")
def r_step():
    """An R step 4 → 36 m² (no outliers): the χ²-gated KF's gate locks out in some runs."""
    spec = ExperimentSpec(
        runs=20,
        epochs=100,
        seed=1,
        noise_schedule="step",
        outliers="none",
        filters=("kf", "oracle-kf", "chi2-kf"),
    )
    return run_experiment(spec)


@pytest.fixture(scope="module")
def quiet():
    """Constant R, no outliers: the KF does not fail."""
    return run_experiment(
        ExperimentSpec(runs=4, epochs=60, seed=5, outliers="none", filters=("kf", "chi2-kf", "sage-husa"))
    )


def _with(res, key, **fields):
    fr = dataclasses.replace(res.runs[key], **fields)
    return dataclasses.replace(res, runs={**res.runs, key: fr})


def test_longest_run_matches_a_loop():
    rng = np.random.default_rng(1)
    b = rng.random((200, 37)) < 0.6
    b[0] = False
    b[1] = True
    length, end = D.longest_run(b)
    for row, n, e in zip(b, length, end, strict=True):
        best = cur = 0
        best_end = 0
        for k, v in enumerate(row):
            cur = cur + 1 if v else 0
            if cur > best:
                best, best_end = cur, k
        assert n == best and (best == 0 or e == best_end)
    assert length[0] == 0 and length[1] == 37 and end[1] == 36


def test_chi2_kf_after_an_r_step_locks_out(r_step):
    ex = D.explain(r_step)
    lock = [e for e in ex if e.kind == "lockout"]
    assert [e.filter for e in lock] == ["chi2-kf"]
    e = lock[0]
    assert e.value >= D.LOCKOUT_MIN_EPOCHS and e.unit == "epochs" and 1 <= e.runs <= 20 and e.of_runs == 20
    # the sentence carries the numbers: the run length, the variance growth, the error reached
    assert f"{int(e.value)} consecutive epochs" in e.sentence
    assert "lock-out" in e.sentence and "variance" in e.sentence and "error in that run reached" in e.sentence
    # … and they are right: that run's streak really is all-rejected epochs
    fr = r_step.runs["chi2-kf"]
    rej = (fr.flags[:, 1:] == REJECTED).all(axis=2)
    assert D.longest_run(rej)[0].max() == e.value
    q = parse_qs(urlparse(e.learn).query)
    assert e.learn.startswith("Learn?") and q["filter"] == ["chi2-kf"]
    assert f"]({e.learn})" in e.markdown()


def test_filters_that_do_not_lock_out_get_no_sentence(r_step, quiet):
    assert not [e for e in D.explain(r_step) if e.filter in ("kf", "oracle-kf")]
    ex = D.explain(quiet)
    assert not [e for e in ex if e.filter == "kf"]
    # Sage–Husa's R̂ really is held at its band in its first epochs; nothing else is said about it
    assert {e.kind for e in ex if e.filter == "sage-husa"} <= {"band"}
    # what is said about the χ²-gated KF is true of its flags (a gate can lock out even with the
    # right R and no outliers: a chance rejection early on, then P grows too slowly to catch up)
    for e in ex:
        if e.filter == "chi2-kf" and e.kind == "lockout":
            fr = quiet.runs["chi2-kf"]
            assert D.longest_run((fr.flags[:, 1:] == REJECTED).all(axis=2))[0].max() == e.value


def _lockout_case(quiet, length):
    """chi2-kf of run 0 rejecting epochs 10 … 10+length−1 while its P grows 3-fold."""
    fr = quiet.runs["chi2-kf"]
    flags = np.zeros_like(fr.flags)
    flags[0, 10 : 10 + length] = REJECTED
    P = fr.P_diag.copy()
    P[0, 10 : 10 + length] *= np.linspace(1.0, 3.0, length)[:, None]
    return _with(quiet, "chi2-kf", flags=flags, P_diag=P)


def test_lockout_threshold(quiet):
    n = D.LOCKOUT_MIN_EPOCHS
    assert not [e for e in D.explain(_lockout_case(quiet, n - 1)) if e.kind == "lockout"]
    e = [e for e in D.explain(_lockout_case(quiet, n)) if e.kind == "lockout"]
    assert len(e) == 1 and e[0].value == n and e[0].runs == 1 and e[0].filter == "chi2-kf"
    assert "t = 10–19 s" in e[0].sentence


def test_rejections_without_growing_p_are_no_lockout(quiet):
    fr = quiet.runs["chi2-kf"]
    flags = np.zeros_like(fr.flags)
    flags[0, 10:30] = REJECTED
    P = fr.P_diag.copy()
    P[0, 9:30] = P[0, 9]  # flat P: not a lock-out
    r = _with(quiet, "chi2-kf", flags=flags, P_diag=P)
    assert not [e for e in D.explain(r) if e.kind == "lockout"]


def test_band_rate(quiet):
    fr = quiet.runs["sage-husa"]
    K, m = quiet.data.K, quiet.data.z.shape[2]
    total = quiet.data.B * K * m
    for share, found in ((0.005, False), (0.02, True)):
        flags = np.zeros_like(fr.flags)
        count = round(share * total)
        idx = np.unravel_index(np.arange(count), (quiet.data.B, K, m))
        flags[idx[0], idx[1] + 1, idx[2]] = R_HAT_AT_BAND
        ex = [e for e in D.explain(_with(quiet, "sage-husa", flags=flags)) if e.kind == "band"]
        assert bool(ex) is found
        if found:
            assert ex[0].value == pytest.approx(100 * count / total) and ex[0].unit == "%"
            # R̂ of this run lies well inside [0.01, 1e4] × R0: only the lower bound fits its trace
            assert "held at the lower bound r_min = 0.01 × R0" in ex[0].sentence
            assert (
                "positive-definiteness" not in ex[0].sentence and "not outlier detections" in ex[0].sentence
            )
            assert parse_qs(urlparse(ex[0].learn).query)["filter"] == ["sage-husa"]
    # a repair (flag 9) is said as one, for a filter with a band too, never as R̂ at its band
    for key in ("kf", "sage-husa"):
        flags = np.zeros_like(quiet.runs[key].flags)
        flags[:, 1:5] = NUMERICAL_FIX
        (e,) = [e for e in D.explain(_with(quiet, key, flags=flags)) if e.filter == key]
        assert e.kind == "numerical_fix" and "covariance repaired" in e.sentence
        assert "band" not in e.sentence


def test_band_bound_named_with_its_share(quiet):
    """R̂ at the band's upper bound on half the flagged epochs: both bounds, each with its share."""
    fr = quiet.runs["sage-husa"]
    R0 = np.diag(quiet.data.model.R0)
    flags = np.zeros_like(fr.flags)
    flags[:, 1:21] = R_HAT_AT_BAND  # 20 of 60 epochs, every channel
    R_hat = fr.R_hat.copy()
    R_hat[:, 1:11] = 1e4 * R0  # the first 10: at r_max × R0
    r = _with(quiet, "sage-husa", flags=flags, R_hat=R_hat)
    (e,) = [e for e in D.explain(r) if e.kind == "band"]
    assert e.value == pytest.approx(100 * 20 / 60)
    s = e.sentence
    assert "lower bound r_min = 0.01 × R0 (σ 0.1× the nominal σ) on 16.7 %" in s
    assert "upper bound r_max = 10000 × R0 (σ 100× the nominal σ) on 16.7 %" in s


def test_band_sides_hold_the_side_the_clamp_used():
    """Whichever eigenvalue the clamp moved (kernel run in Python), band_sides allows that side."""
    from navlab.filters.sage_husa.kernels import clamp_to_band

    rng = np.random.default_rng(3)
    lo, hi, m = 0.25, 16.0, 5
    R0 = np.diag(rng.uniform(0.01, 4.0, m))
    L0 = np.linalg.cholesky(R0)
    seen = set()
    for _ in range(300):
        A = rng.standard_normal((m, m))
        C = A @ A.T * 10 ** rng.uniform(-2, 2) - rng.uniform(0, 2) * np.eye(m)  # may leave [lo, hi]
        R = L0 @ C @ L0.T
        out, changed = clamp_to_band(R, R0, L0, lo, hi)
        if not changed.any():
            continue
        w = np.linalg.eigvalsh(C)
        low, up = D.band_sides(np.array([np.sum(np.diag(out) / np.diag(R0))]), m, lo, hi)
        if w.min() < lo:
            assert low[0]
            seen.add("lo")
        if w.max() > hi:
            assert up[0]
            seen.add("hi")
    assert seen == {"lo", "hi"}


def test_replacement_runaway_threshold(quiet):
    fr = quiet.runs["kf"]
    n = D.REPLACEMENT_CHAIN_MIN
    for length, found in ((n - 1, False), (n, True)):
        flags = np.zeros_like(fr.flags)
        flags[1, 20 : 20 + length, 0] = REPLACED
        ex = [e for e in D.explain(_with(quiet, "kf", flags=flags)) if e.kind == "runaway"]
        assert bool(ex) is found
        if found:
            assert ex[0].value == n and ex[0].runs == 1 and "random walk" in ex[0].sentence


@pytest.mark.slow
def test_nnmfukf_runs_away_and_its_guarded_variant_does_not():
    r = run_experiment(
        ExperimentSpec(scenario="gps-ins-rtk", filters=("nnmfukf", "nnmfukf-guarded"), runs=2, seed=1)
    )
    ex = D.explain(r, kinds=("runaway",))
    assert [e.filter for e in ex] == ["nnmfukf"]
    assert ex[0].value >= D.REPLACEMENT_CHAIN_MIN and "`nnmfukf-guarded` caps the chain" in ex[0].sentence


def test_divergence(quiet):
    fr = quiet.runs["kf"]
    at = fr.diverged_at.copy()
    at[[0, 2]] = [30, 17]
    x = fr.x.copy()
    x[0, 30:] = np.nan
    x[2, 17:] = np.nan
    r = _with(quiet, "kf", diverged_at=at, x=x)
    (e,) = [e for e in D.explain(r) if e.kind == "divergence" and e.filter == "kf"]
    assert e.value == 2 and "2 of 4 runs diverged (the first at epoch 17" in e.sentence


def test_kinds_filter_and_dicts(r_step):
    assert D.explain(r_step, kinds=("divergence",)) == []
    d = D.explain(r_step)[0].to_dict()
    assert set(d) == {"filter", "label", "kind", "value", "unit", "runs", "of_runs", "sentence", "learn"}
    with pytest.raises(ValueError, match="unknown kinds"):
        D.explain(r_step, kinds=("nope",))


def test_the_library_does_not_import_streamlit():
    import ast
    from pathlib import Path

    tree = ast.parse(Path(D.__file__).read_text())
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import | ast.ImportFrom) for a in n.names}
    mods = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert "streamlit" not in names and "streamlit" not in mods


def test_the_no_flag_shortcut_finds_what_the_full_rules_find(r_step, quiet, monkeypatch):
    """A filter without flags 2/3, 4 or 9 skips the run-length rules: the same explanations as
    applying them to every filter."""
    shortcut = [D.explain(r_step), D.explain(quiet)]
    assert any(not D._any_flag(fr, REJECTED) for fr in r_step.runs.values())  # the shortcut is taken
    monkeypatch.setattr(D, "_any_flag", lambda fr, *codes: True)
    full = [D.explain(r_step), D.explain(quiet)]
    assert [[e.to_dict() for e in x] for x in shortcut] == [[e.to_dict() for e in x] for x in full]
