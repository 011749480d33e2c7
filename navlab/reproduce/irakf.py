"""Reproduction of Ge, Zhang, Tang 2020 (IRAKF), §3: 2-D tracking with isolated / continuous outliers.

The paper (§3, Figs. 2–3) runs 100 Monte Carlo runs of the ``cv2d`` scenario (ALGORITHMS.md §8.2)
with outliers on the x-position measurement — experiment 1 ``isolated``: every 5 epochs in 20–70,
N(10, 64); experiment 2 ``continuous``: epochs 50–70, N(0, 64) — and compares SKF, RRAE, RAKF,
RSSHAKF and IRAKF. Its claims (text of §3):

* isolated: position RMSE IRAKF 1.5942 m, RRAE 2.1969 m (IRAKF 27.43 % better), RSSHAKF 2.1818 m;
  IRAKF the most accurate;
* continuous: IRAKF 1.4663 m and 0.3367 m/s, RRAE 1.9583 m and 0.5475 m/s; IRAKF the most
  accurate; SKF, RAKF and RSSHAKF have a maximum position error above 10 m during epochs 50–70.

The paper's "位置RMSE" is not defined beyond the per-epoch eq. 9 and its figures show the x axis:
the claims use navlab's default reading, the x-position RMSE pooled over k = 1 … K and runs
(§8.2, §10 #18); the other plausible readings (mean of the per-epoch RMSE, the 2-D norm, per axis,
the outlier window) are in the detailed readings. The comparators RRAE, RAKF and RSSHAKF are
RECONSTRUCTIONS (§4.7–4.9) and the paper gives neither the RAE window, the detector threshold C,
P0 nor the run length: those are navlab's documented defaults (§10).
"""

from __future__ import annotations

import numpy as np

from navlab.experiment import ExperimentSpec
from navlab.reproduce import register
from navlab.reproduce.engine import (
    Alternative,
    Bound,
    Close,
    Curve,
    Experiment,
    Margin,
    Number,
    Ranking,
    Ref,
    Reproduction,
    Untested,
    component_error,
    mean_rmse,
    peak_rmse,
    pooled_rmse,
    rate,
    run_peak,
)

PAPER = (
    "Ge, Zhang, Tang 2020, Navigation Positioning and Timing 7(1) (IRAKF), §3, "
    "doi:10.19306/j.cnki.2095-8110.2020.01.007"
)
DEFAULT_RUNS = 100  # the paper's Monte Carlo size
FILTERS = ("kf", "rrae", "rakf", "rsshakf", "irakf", "oracle-kf")
NAMES = {
    "kf": "SKF",
    "rrae": "RRAE",
    "rakf": "RAKF",
    "rsshakf": "RSSHAKF",
    "irakf": "IRAKF",
    "oracle-kf": "oracle KF",
}
PAPER_MAX_ABOVE = 10.0  # continuous: SKF, RAKF, RSSHAKF "maximum position error > 10 m"

WHY = {
    "rrae": "RRAE is a RECONSTRUCTION (§4.7: IGG-III middle zone as equivalent variance, k1 = 5); "
    "the 2018 paper was not retrievable",
    "rsshakf": "RSSHAKF is a RECONSTRUCTION (§4.9); its RMSE is heavy-tailed over seeds (a few runs run "
    "away early when the Sage–Husa R̂ and the variance inflation feed each other)",
    "rakf": "RAKF is a RECONSTRUCTION from the abstract (§4.8)",
    "irakf": "the paper leaves the RAE window, C, P0 and the run length open (navlab: M = 10, C = 3, "
    "P0 = diag(4, 1, 4, 1), K = 100, §10)",
}
WHY_CONT = (
    "ALGORITHMS.md §4.6: no reasonable variant (window 5/20, k0/k1, P_ref policy, excluding rejected "
    "residuals) gets IRAKF below ≈ 1.9 m in experiment 2 — treated as not reproducible"
)


def outlier_window(data) -> np.ndarray:
    """Epochs from the first to the last contaminated one (20–70 or 50–70)."""
    hit = np.flatnonzero(data.outlier_mask.any(axis=(0, 2)))
    k = np.arange(data.K + 1)
    if not hit.size:
        return np.zeros(data.K + 1, dtype=bool)
    return (k >= hit[0]) & (k <= hit[-1])


def _flag_share(codes, among_outliers: bool):
    def hits(data, fr):
        W = np.arange(data.K + 1) >= 1
        mask = data.outlier_mask[:, W] if among_outliers else ~data.outlier_mask[:, W]
        flagged = np.isin(fr.flags[:, W], codes) & mask
        return flagged.sum(axis=(1, 2)), mask.sum(axis=(1, 2))

    return hits


def _quantities():
    ex, vx, ey = component_error((0,)), component_error((1,)), component_error((2,))
    pos2, vel2 = component_error((0, 2)), component_error((1, 3))
    pos_axis, vel_axis = component_error((0, 2), np.sqrt(0.5)), component_error((1, 3), np.sqrt(0.5))
    qs = []
    for q, x, two, axis, unit in (("pos", ex, pos2, pos_axis, "m"), ("vel", vx, vel2, vel_axis, "m/s")):
        qs += [
            pooled_rmse(
                f"rmse_x_{q}", unit, x, help="default reading: pooled over k = 1…K and runs, x (§8.2)"
            ),
            mean_rmse(f"mean_rmse_x_{q}", unit, x, help="mean over k = 1…K of the per-epoch RMSE (eq. 9), x"),
            pooled_rmse(f"rmse_{q}_2d", unit, two, help="pooled, 2-D error norm"),
            pooled_rmse(f"rmse_{q}_per_axis", unit, axis, help="pooled, 2-D norm per axis"),
            pooled_rmse(f"rmse_x_{q}_window", unit, x, outlier_window, help="pooled over the outlier window"),
            mean_rmse(
                f"mean_rmse_x_{q}_window", unit, x, outlier_window, help="mean per-epoch RMSE, outlier window"
            ),
        ]
    qs += [
        peak_rmse(
            "peak_rmse_x_pos_window",
            "m",
            ex,
            outlier_window,
            help="largest per-epoch RMSE of x in the outlier window (what Fig. 3 plots if it shows RMSE)",
        ),
        run_peak(
            "run_peak_x_pos_window",
            "m",
            ex,
            outlier_window,
            help="mean over runs of each run's largest |e_x| in the outlier window (Fig. 3 if it is one run)",
        ),
        pooled_rmse("rmse_y_pos", "m", ey, help="clean channel; paper Fig. 2(c): all but RRAE comparable"),
        pooled_rmse(
            "rmse_y_vel", "m/s", component_error((3,)), help="clean channel; paper Fig. 2(d): as Fig. 2(c)"
        ),
        rate(
            "rejected_outliers_pct",
            _flag_share((2, 3), True),
            "channels rejected (flags 2/3) among outliers",
            False,
        ),
        rate(
            "flagged_outliers_pct",
            _flag_share((1, 2, 3, 4, 5), True),
            "any outlier flag among outliers",
            False,
        ),
        rate("rejected_clean_pct", _flag_share((2, 3), False), "false rejections among clean channel-epochs"),
    ]
    return tuple(qs)


_OTHERS = ("kf", "rrae", "rakf", "rsshakf")  # the filters IRAKF is ranked against

# the paper's sentences (§3, the discussion of Figs. 2 and 3; §4 the conclusions)
Q_FIG2AB = (
    "由图2(a)和图2(b)可知,当出现孤立型量测异常时,IRAKF能够有效抑制异常值对滤波结果的影响,说明所提算法能够"
    "提高滤波精度且具有一定的鲁棒性。SKF滤波结果产生了较大的偏差"
)
Q_RRAE_ISO = "RRAE算法可以有效抵制孤立型异常的干扰,并且具有自适应调节量测噪声方差阵的能力"
Q_ISO_NUM = "前者位置RMSE为1.5942m,后者位置RMSE为2.1969m,IRAKF位置精度提高了27.43%"
Q_RAKF = "RAKF受量测异常影响严重,这主要是因为RAKF算法中更加依赖量测值"
Q_RSSHAKF = "虽然RSSHAKF能够在一定程度上抑制量测异常的干扰,但较IRAKF其效果有待提高,RSSHAKF位置RMSE为2.1818m"
Q_FIG2CD = "由图2(c)和图2(d)可知,在未有量测异常时,除RRAE算法波动较大外,其余算法滤波效果相当"
Q_CONT = "当连续型异常量测发生时,IRAKF仍能够有效抑制,其位置RMSE为1.4663m,速度RMSE为0.3367m/s"
Q_PEAK = "SKF、RAKF与RSSHAKF滤波位置最大误差均超过了10m,且在50~70历元间持续振荡"
Q_RRAE_CONT = (
    "虽然RRAE滤波效果优于除IRAKF外的其他算法,其位置RMSE为1.9583m,速度RMSE为0.5475m/s,但其存在滤波发散的风险"
)
W_ISO, W_CONT = "§3, Fig. 2(a–b) text", "§3, Fig. 3 text"
CHOSEN_RSSHAKF = (
    "RSSHAKF reconstructed with the Sage–Husa update on every channel (§10 #17); its documented "
    "variant exclude_outliers is the alternative"
)
RSSHAKF_EXCL = "rsshakf-excl"  # the experiment of the alternative RSSHAKF reading (same runs)
SINGLE_RUN = (
    "single-run reading of Fig. 3 (the mean over runs of each run's largest |e_x| in epochs 50–70, "
    "run_peak_x_pos_window) instead of the peak of the per-epoch RMSE"
)


def _iso_best(exp: str, quantity: str) -> tuple:
    """IRAKF best in ``exp``, and the same under the RSSHAKF variant that skips Sage–Husa on the
    outlier channels (ALGORITHMS.md §10 #17: it 'beats IRAKF in exp. 1').
    """
    R = Ref
    main = tuple(R(exp, k) for k in _OTHERS)
    alt = tuple(R(f"{exp}-{RSSHAKF_EXCL}" if k == "rsshakf" else exp, k) for k in _OTHERS)
    return main, alt


def _isolated_claims() -> list:
    """The paper's numbers, margin and rankings under isolated outliers (Fig. 2)."""
    return _iso_number_claims() + _iso_ranking_claims() + _iso_clean_channel_claims()


def _iso_number_claims() -> list:
    """Isolated outliers: the paper's x-position RMSEs and IRAKF's margin over RRAE (§3's text)."""
    iso = "isolated"
    R = Ref
    return [
        Number(
            "iso-irakf-pos",
            "isolated: IRAKF x-position RMSE 1.5942 m",
            R(iso, "irakf"),
            "rmse_x_pos",
            1.5942,
            WHY["irakf"],
            where=W_ISO,
            quote=Q_ISO_NUM,
        ),
        Number(
            "iso-rrae-pos",
            "isolated: RRAE x-position RMSE 2.1969 m",
            R(iso, "rrae"),
            "rmse_x_pos",
            2.1969,
            WHY["rrae"],
            where=W_ISO,
            quote=Q_ISO_NUM,
        ),
        Number(
            "iso-rsshakf-pos",
            "isolated: RSSHAKF x-position RMSE 2.1818 m",
            R(iso, "rsshakf"),
            "rmse_x_pos",
            2.1818,
            WHY["rsshakf"],
            where=W_ISO,
            quote=Q_RSSHAKF,
            chosen=CHOSEN_RSSHAKF,
            alternatives=(
                Alternative(
                    "RSSHAKF exclude_outliers",
                    Number("", "", R(f"{iso}-{RSSHAKF_EXCL}", "rsshakf"), "rmse_x_pos", 2.1818),
                ),
            ),
        ),
        Margin(
            "iso-margin",
            "isolated: IRAKF 27.43 % more accurate than RRAE",
            R(iso, "irakf"),
            R(iso, "rrae"),
            "rmse_x_pos",
            -0.2743,
            note="(IRAKF − RRAE)/RRAE; ALGORITHMS.md §4.7: the reconstructed RRAE lands inside the IRAKF "
            "band, so the paper's margin is not expected to reproduce",
            where=W_ISO,
            quote=Q_ISO_NUM,
        ),
    ]


def _iso_ranking_claims() -> list:
    """Isolated outliers, the x channel (Figs. 2(a)–(b)): which filter is the most accurate."""
    iso = "isolated"
    R = Ref
    best, best_alt = _iso_best(iso, "rmse_x_pos")
    rank_alt = Ranking("iso-best", "", R(iso, "irakf"), best_alt, "rmse_x_pos", where=W_ISO, quote=Q_ISO_NUM)
    return [
        Ranking(
            "iso-best",
            "isolated: IRAKF the most accurate (x position)",
            R(iso, "irakf"),
            best,
            "rmse_x_pos",
            where=W_ISO,
            quote=f"{Q_FIG2AB}; {Q_RSSHAKF}",
            chosen=CHOSEN_RSSHAKF,
            alternatives=(Alternative("RSSHAKF exclude_outliers", rank_alt),),
        ),
        Ranking(
            "iso-irakf-vs-skf-vel",
            "isolated: IRAKF more accurate than SKF (x velocity, Fig. 2(b))",
            R(iso, "irakf"),
            (R(iso, "kf"),),
            "rmse_x_vel",
            where="§3, Fig. 2(b) text",
            quote=Q_FIG2AB,
        ),
        Ranking(
            "iso-rrae-vs-skf",
            "isolated: RRAE resists the isolated outliers (RRAE better than SKF, x position)",
            R(iso, "rrae"),
            (R(iso, "kf"),),
            "rmse_x_pos",
            where=W_ISO,
            quote=Q_RRAE_ISO,
        ),
        Ranking(
            "iso-rakf-hit",
            "isolated: RAKF severely affected by the outliers (RAKF worse than RRAE, RSSHAKF and IRAKF, "
            "x position)",
            R(iso, "rakf"),
            (R(iso, "rrae"), R(iso, "rsshakf"), R(iso, "irakf")),
            "rmse_x_pos",
            "read as: worse than every filter the paragraph says resists the outliers",
            worst=True,
            where=W_ISO,
            quote=Q_RAKF,
        ),
        Ranking(
            "iso-rsshakf-vs-skf",
            "isolated: RSSHAKF suppresses the outliers to a degree (RSSHAKF better than SKF, x position)",
            R(iso, "rsshakf"),
            (R(iso, "kf"),),
            "rmse_x_pos",
            where=W_ISO,
            quote=Q_RSSHAKF,
            chosen=CHOSEN_RSSHAKF,
        ),
    ]


def _iso_clean_channel_claims() -> list:
    """Isolated outliers, the clean y channel (Figs. 2(c)–(d))."""
    iso = "isolated"
    R = Ref
    y_four = ("kf", "rakf", "rsshakf", "irakf")
    out = []
    for q, fig, word in (("rmse_y_pos", "2(c)", "position"), ("rmse_y_vel", "2(d)", "velocity")):
        out += [
            Close(
                f"iso-y-{word[:3]}-comparable",
                f"isolated, clean y channel: SKF, RAKF, RSSHAKF, IRAKF comparable (y {word}, Fig. {fig})",
                tuple(R(iso, k) for k in y_four),
                q,
                note="ALGORITHMS.md §4.6: the M = 10 window costs IRAKF ≈ 12 % on the clean y channel",
                where=f"§3, Fig. {fig} text",
                quote=Q_FIG2CD,
                chosen="IRAKF's window M = 10 (the paper gives none, §10 #12)",
            ),
            Ranking(
                f"iso-y-{word[:3]}-rrae",
                f"isolated, clean y channel: RRAE fluctuates more than the others (y {word}, Fig. {fig})",
                R(iso, "rrae"),
                tuple(R(iso, k) for k in y_four),
                q,
                "'fluctuates more' read as a larger RMSE on the clean channel",
                worst=True,
                where=f"§3, Fig. {fig} text",
                quote=Q_FIG2CD,
            ),
        ]
    return out


def _continuous_claims() -> list:
    """The paper's numbers, rankings and peak errors (Fig. 3) under continuous outliers."""
    return _cont_number_claims() + _cont_ranking_claims() + _cont_peak_claims() + _cont_untested_claims()


def _cont_number_claims() -> list:
    """Continuous outliers: the paper's x RMSEs of IRAKF and RRAE (§3's text)."""
    cont = "continuous"
    R = Ref
    return [
        Number(
            "cont-irakf-pos",
            "continuous: IRAKF x-position RMSE 1.4663 m",
            R(cont, "irakf"),
            "rmse_x_pos",
            1.4663,
            f"{WHY['irakf']}; {WHY_CONT}",
            where=W_CONT,
            quote=Q_CONT,
        ),
        Number(
            "cont-irakf-vel",
            "continuous: IRAKF x-velocity RMSE 0.3367 m/s",
            R(cont, "irakf"),
            "rmse_x_vel",
            0.3367,
            WHY["irakf"],
            where=W_CONT,
            quote=Q_CONT,
        ),
        Number(
            "cont-rrae-pos",
            "continuous: RRAE x-position RMSE 1.9583 m",
            R(cont, "rrae"),
            "rmse_x_pos",
            1.9583,
            WHY["rrae"],
            where=W_CONT,
            quote=Q_RRAE_CONT,
        ),
        Number(
            "cont-rrae-vel",
            "continuous: RRAE x-velocity RMSE 0.5475 m/s",
            R(cont, "rrae"),
            "rmse_x_vel",
            0.5475,
            WHY["rrae"],
            where=W_CONT,
            quote=Q_RRAE_CONT,
        ),
    ]


def _cont_ranking_claims() -> list:
    """Continuous outliers: IRAKF the most accurate, RRAE second (x position and velocity)."""
    cont = "continuous"
    R = Ref
    cl = []
    for q, word in (("rmse_x_pos", "position"), ("rmse_x_vel", "velocity")):
        cl.append(
            Ranking(
                f"cont-best-{word[:3]}",
                f"continuous: IRAKF the most accurate (x {word})",
                R(cont, "irakf"),
                tuple(R(cont, k) for k in _OTHERS),
                q,
                where=W_CONT,
                quote=f"{Q_CONT}; {Q_RRAE_CONT}",
            )
        )
    for q, word in (("rmse_x_pos", "position"), ("rmse_x_vel", "velocity")):
        cl.append(
            Ranking(
                f"cont-rrae-second-{word[:3]}",
                f"continuous: RRAE better than SKF, RAKF and RSSHAKF (x {word})",
                R(cont, "rrae"),
                tuple(R(cont, k) for k in ("kf", "rakf", "rsshakf")),
                q,
                where=W_CONT,
                quote=Q_RRAE_CONT,
            )
        )
    return cl


def _cont_peak_claims() -> list:
    """Continuous outliers: the peak position errors in epochs 50–70 (Fig. 3)."""
    cont = "continuous"
    R = Ref
    peak_alt = Ranking(
        "",
        "",
        R(cont, "irakf"),
        tuple(R(cont, k) for k in ("kf", "rakf", "rsshakf")),
        "run_peak_x_pos_window",
    )
    cl = [
        Ranking(
            "cont-peak",
            "continuous: IRAKF's peak position error below SKF's, RAKF's, RSSHAKF's",
            R(cont, "irakf"),
            tuple(R(cont, k) for k in ("kf", "rakf", "rsshakf")),
            "peak_rmse_x_pos_window",
            "read as the peak of the per-epoch RMSE in epochs 50–70",
            where=W_CONT,
            quote=f"{Q_CONT}; {Q_PEAK}",
            alternatives=(Alternative(SINGLE_RUN, peak_alt),),
        )
    ]
    for k in ("kf", "rakf", "rsshakf"):
        cl.append(
            Bound(
                f"cont-{k}-peak",
                f"continuous: {NAMES[k]}'s maximum position error above 10 m (Fig. 3)",
                R(cont, k),
                "peak_rmse_x_pos_window",
                PAPER_MAX_ABOVE,
                True,
                "read as the peak of the per-epoch RMSE in epochs 50–70",
                where=W_CONT,
                quote=Q_PEAK,
                alternatives=(
                    Alternative(
                        SINGLE_RUN,
                        Bound("", "", R(cont, k), "run_peak_x_pos_window", PAPER_MAX_ABOVE, True),
                    ),
                ),
            )
        )
    return cl


def _cont_untested_claims() -> list:
    """What the text gives too little to test, and the conclusions' untestable claims."""
    return [
        Untested(
            "cont-oscillate",
            "continuous: SKF, RAKF and RSSHAKF keep oscillating during epochs 50–70 (Fig. 3)",
            "the paper gives no measure of 'oscillation' (an impression of Fig. 3); the per-epoch curves "
            "are in the reproduction's curve files",
            where=W_CONT,
            quote=Q_PEAK,
        ),
        Untested(
            "cont-rrae-risk",
            "continuous: RRAE carries a risk of divergence",
            "a risk, not an outcome of the paper's runs: no rate or criterion is given (the divergences of "
            "every filter are counted in the detailed readings)",
            where=W_CONT,
            quote=Q_RRAE_CONT,
        ),
        Untested(
            "concl-detection",
            "conclusion 1: the dual detection (with a parallel SKF) detects outliers more effectively",
            "no experiment of the paper compares detection with and without the parallel SKF, and it "
            "reports no detection rate",
            where="§4, conclusion 1",
            quote="本文所提出的改进滤波方案采用双重检测方式,通过新息统计量检测量测异常,提高了异常检测的有效性",
        ),
        Untested(
            "concl-cost",
            "conclusion 3: the dual-filter structure increases the computation to some extent",
            "a cost claim without a number; the reproduction judges accuracy only (runtimes on a shared "
            "machine are not a paired statistic of the runs)",
            where="§4, conclusion 3",
            quote="本文所提改进抗差自适应滤波方案,因采用了双滤波结构,因此在一定程度上增加了计算量",
        ),
    ]


def _claims():
    return tuple(_isolated_claims() + _continuous_claims())


REPRODUCTION = register(
    Reproduction(
        key="irakf",
        title="IRAKF vs SKF, RRAE, RAKF, RSSHAKF on 2-D tracking with isolated / continuous outliers "
        "(Ge, Zhang, Tang 2020, §3)",
        paper=PAPER,
        experiments=(
            *(
                Experiment(
                    name,
                    ExperimentSpec(scenario="cv2d", filters=FILTERS, runs=DEFAULT_RUNS, outliers=name),
                    label,
                )
                for name, label in (
                    ("isolated", "experiment 1: isolated outliers every 5 epochs in 20–70"),
                    ("continuous", "experiment 2: continuous outliers in epochs 50–70"),
                )
            ),
            Experiment(
                f"isolated-{RSSHAKF_EXCL}",
                ExperimentSpec(
                    scenario="cv2d",
                    filters=("rsshakf",),
                    runs=DEFAULT_RUNS,
                    outliers="isolated",
                    filter_params={"rsshakf": {"exclude_outliers": True}},
                ),
                "not in the paper: experiment 1's runs, RSSHAKF with Sage–Husa skipped on outlier channels "
                "(the alternative reconstruction, ALGORITHMS.md §10 #17)",
            ),
        ),
        quantities=_quantities(),
        claims=_claims(),
        curves=(
            Curve("x_pos", "m", component_error((0,))),
            Curve("x_vel", "m/s", component_error((1,))),
            Curve("y_pos", "m", component_error((2,))),
        ),
        names=NAMES,
        paper_runs=DEFAULT_RUNS,
        notes={f"{k}:rmse_x_pos": v for k, v in WHY.items()},
    )
)
