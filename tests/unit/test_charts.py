"""Readable charts (issue #11 item 5), checked on the figure dicts: axis types, legend position,
tick settings, truth drawn last, one colour per filter on every page."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from navlab.experiment import ExperimentSpec, run_experiment
from navlab.learn import TinySpec, step_through
from navlab.ui import figures as F
from navlab.ui import realdata as RD
from navlab.ui import reproduce as RP
from navlab.ui.colors import TRUTH_COLOR, filter_colors
from navlab.ui.learn import overview_figure

NICE = {m * 10.0**d for d in range(-8, 9) for m in (1, 2, 5)}


@pytest.fixture(scope="module")
def mixture():
    """The brief's case: an R step 4 → 36 m² with 10 % outliers of 10σ (outlier variance 400–3600 m²)."""
    spec = ExperimentSpec(
        runs=40,
        epochs=100,
        seed=2,
        noise_schedule="step",
        outliers="mixture",
        contamination=0.1,
        outlier_scale=10.0,
        filters=("kf", "oracle-kf", "chi2-kf", "sage-husa", "vb-akf"),
    )
    return run_experiment(spec)


@pytest.fixture(scope="module")
def small():
    return run_experiment(ExperimentSpec(runs=6, epochs=40, seed=3))


@pytest.fixture(scope="module")
def outcome():
    """A tiny reproduction outcome (vbekf: 1 seed × 3 runs) for the Reproduce figures."""
    from navlab.reproduce import REPRODUCTIONS

    return REPRODUCTIONS["vbekf"].evaluate(runs=3, seeds=1, seed=1)


def _d(fig):
    return fig.to_dict()["layout"]


def assert_legend_below(fig):
    lg = _d(fig)["legend"]
    assert lg["orientation"] == "h"
    assert lg["yref"] == "container" and lg["y"] == 0 and lg["yanchor"] == "bottom"


def assert_clean_log(axis: dict):
    """One label per decade, or labels only at 1-2-5 values: never every minor tick."""
    assert axis["type"] == "log"
    if axis.get("tickmode") == "array":
        vals = axis["tickvals"]
        assert len(vals) >= 2
        assert all(any(np.isclose(v, n, rtol=1e-9) for n in NICE) for v in vals), vals
        assert [float(t) for t in axis["ticktext"]] == pytest.approx(vals)
    else:
        assert axis["dtick"] == 1 and axis.get("tickmode") == "linear"


# ---------------------------------------------------------------------------------- R̂ chart
def test_r_vs_rhat_is_log_by_default_and_linear_on_request(mixture):
    assert _d(F.r_vs_rhat(mixture, 0))["yaxis"]["type"] == "log"
    assert _d(F.r_vs_rhat(mixture, 0, outlier_strip=True))["yaxis"]["type"] == "log"
    assert _d(F.r_vs_rhat(mixture, 0, log_y=False))["yaxis"]["type"] == "linear"


@pytest.mark.parametrize("strip", [False, True])
@pytest.mark.parametrize("as_std", [False, True])
def test_truth_is_the_last_trace_black_and_on_a_halo(mixture, strip, as_std):
    fig = F.r_vs_rhat(mixture, 0, outlier_strip=strip, as_std=as_std)
    truth, halo = fig.data[-1], fig.data[-2]
    assert truth.name == ("true σ(t) (schedule)" if as_std else "true R(t) (schedule)")
    assert truth.line.color == TRUTH_COLOR and truth.line.width >= 3
    assert halo.line.color == "#ffffff" and halo.line.width > truth.line.width and halo.showlegend is False
    want = mixture.data.R_schedule[:, 0]
    np.testing.assert_allclose(truth.y, np.sqrt(want) if as_std else want, rtol=1e-6)


def _only(res, keys):
    return dataclasses.replace(res, runs={k: res.runs[k] for k in keys})


@pytest.mark.parametrize("log_y", [True, False])
def test_contaminated_epochs_never_set_the_axis_range(mixture, log_y):
    """The oracle's R̂ is the variance drawn, outliers included (400–3600 m²): the axis must show
    the true step 4 → 36 m², not that (the default Compare filters on an R step)."""
    d = mixture.data
    oracle = mixture.runs["oracle-kf"].R_hat[:, 1:, 0]
    assert np.quantile(oracle, 0.95) >= 399  # the band does reach the outlier variance
    fig = F.r_vs_rhat(_only(mixture, ("kf", "oracle-kf", "chi2-kf")), 0, log_y=log_y)
    ax = _d(fig)["yaxis"]
    lo, hi = (10.0 ** np.array(ax["range"])) if log_y else np.array(ax["range"])
    assert hi >= d.R_schedule[:, 0].max()  # the whole true R(t) is inside
    assert lo <= d.R_schedule[:, 0].min()
    assert hi < 100  # … and no outlier variance (≥ 400 m²) sets the top
    assert "cut off" in _d(fig)["title"]["text"]  # and the chart says so


def test_an_adaptive_filters_own_rhat_at_clean_epochs_does_set_the_range(mixture):
    """What a filter estimates after absorbing outliers is its R̂, not a contaminated-epoch
    variance: it stays on the chart (but the oracle's 3600 m² outliers still do not)."""
    fr = mixture.runs["sage-husa"]
    v = fr.R_hat[:, 1:, 0]
    clean_hi = np.nanmax(F.nan_quantiles(np.where(mixture.data.outlier_mask[:, 1:, 0], np.nan, v), (0.9,)))
    ax = _d(F.r_vs_rhat(mixture, 0))["yaxis"]
    hi = 10.0 ** ax["range"][1]
    assert clean_hi <= hi < 3600


def test_without_outliers_nothing_is_cut_off():
    r = run_experiment(ExperimentSpec(runs=6, epochs=60, noise_schedule="step", outliers="none"))
    lay = _d(F.r_vs_rhat(r, 0))
    assert "cut off" not in lay["title"]["text"]
    lo, hi = 10.0 ** np.array(lay["yaxis"]["range"])
    for tr in F.r_vs_rhat(r, 0).data:
        y = np.asarray(tr.y, float)
        y = y[np.isfinite(y) & (y > 0)]
        assert (y <= hi).all() and (y >= lo).all()


def test_rhat_axis_has_units_and_clean_ticks(mixture):
    lay = _d(F.r_vs_rhat(mixture, 0, outlier_strip=True))
    assert lay["yaxis"]["title"]["text"] == "R (m²)"
    # one time axis, under the outlier strip (the panels' axes match it): the last axis pair
    n = max(int(k[5:] or 1) for k in lay if k.startswith("xaxis"))
    assert lay[f"xaxis{n}"]["title"]["text"] == "time (s)" and lay["xaxis"]["matches"] == f"x{n}"
    assert lay[f"yaxis{n}"]["title"]["text"] == "share of runs"
    assert_clean_log(lay["yaxis"])
    assert _d(F.r_vs_rhat(mixture, 0, as_std=True))["yaxis"]["title"]["text"] == "σ (m)"


# ------------------------------------------------------------------------------ log ticks
@pytest.mark.parametrize(
    ("lo", "hi"), [(4, 4), (4, 36), (1, 9), (1.6, 30), (0.02, 300), (0.1, 1000), (3e-7, 4e-7), (7, 7.5)]
)
def test_log_axis_ticks_are_clean_and_cover_the_data(lo, hi):
    ax = F.log_axis(lo, hi)
    assert_clean_log(ax)
    r0, r1 = 10.0 ** np.array(ax["range"])
    assert r0 <= lo and r1 >= hi
    if ax.get("tickmode") == "array":  # the data lie between labelled values
        assert min(ax["tickvals"]) <= lo * 1.0001 and max(ax["tickvals"]) >= hi / 1.0001


def test_every_log_axis_of_a_figure_gets_clean_ticks(small):
    for fig in (F.nis_vs_chi2(small), F.error_vs_time(small, "pos", log_y=True)):
        assert_clean_log(_d(fig)["yaxis"])
    df = pd.DataFrame(
        {
            "value": [0.01, 0.1, 1.0] * 2,
            "filter": ["kf"] * 3 + ["chi2-kf"] * 3,
            "label": ["KF"] * 3 + ["χ²-gated KF"] * 3,
            "metric_value": [1.0, 3.0, 40.0, 1.0, 2.0, 5.0],
        }
    )
    lay = _d(F.sweep_lines(df, "contamination", "RMSE (m)", log_x=True, log_y=True))
    assert_clean_log(lay["xaxis"])
    assert_clean_log(lay["yaxis"])


def test_nan_quantiles_equal_numpy():
    rng = np.random.default_rng(0)
    v = rng.standard_normal((50, 7))
    v[rng.random(v.shape) < 0.3] = np.nan
    v[:, 3] = np.nan
    v[1:, 4] = np.nan  # one value
    qs = (0.1, 0.5, 0.9)
    with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
        want = np.nanquantile(v, qs, axis=0)
    np.testing.assert_allclose(F.nan_quantiles(v, qs), want, rtol=1e-12, equal_nan=True)


# -------------------------------------------------------------------- legends and titles
def _all_figures(small, mixture, outcome):
    """One of every figure builder of every page (Compare, Noise, Sweep, Reproduce, Learn, Real data)."""
    figs = {
        "error_vs_time": F.error_vs_time(small, "pos"),
        "r_vs_rhat": F.r_vs_rhat(mixture, 0),
        "r_vs_rhat_strip": F.r_vs_rhat(mixture, 0, outlier_strip=True),
        "nis_vs_chi2": F.nis_vs_chi2(small),
        "internals": F.internals_vs_time(mixture, "d_k"),
    }
    df = pd.DataFrame(
        {"value": [0.0, 0.1] * 2, "filter": ["kf"] * 2 + ["chi2-kf"] * 2, "label": ["KF"] * 2 + ["χ²"] * 2}
    )
    df["metric_value"] = [1.0, 2.0, 1.5, 1.7]
    figs["sweep_lines"] = F.sweep_lines(df, "contamination", "RMSE (m)")
    figs["repro_claims"] = RP.claims_figure(outcome)
    figs["repro_curve"] = RP.curve_figure(outcome, next(iter(outcome.curves)))
    figs["learn"] = overview_figure(step_through("chi2-kf", TinySpec(epochs=12)), 3)
    figs["real_track"] = RD.track_figure(mixture)
    figs["real_rhat"] = RD.rhat_figure(mixture, 0)
    figs["real_flags"] = RD.flags_figure(mixture)
    return figs


def test_every_legend_sits_below_the_plot_and_titles_push_the_margin(small, mixture, outcome):
    for name, fig in _all_figures(small, mixture, outcome).items():
        assert_legend_below(fig), name
        lay = _d(fig)
        t = lay.get("title", {})
        if t.get("text"):
            assert t["yref"] == "paper" and t["yanchor"] == "bottom" and t["automargin"], name
        for k, ax in lay.items():
            if k[:5] in ("xaxis", "yaxis"):
                assert ax.get("automargin") is True, (name, k)


def test_every_axis_is_titled(small, mixture, outcome):
    for name, fig in _all_figures(small, mixture, outcome).items():
        lay = _d(fig)
        for k, ax in lay.items():
            if k[:5] in ("xaxis", "yaxis") and not ax.get("matches") and ax.get("type") != "category":
                if name == "learn" and k.startswith("xaxis") and k != "xaxis4":
                    continue  # shared x axis: titled once, under the bottom panel
                if name in ("real_flags", "repro_claims") and k == "yaxis":
                    continue  # the tick labels are the names (filters; the paper's claims)
                assert ax.get("title", {}).get("text"), (name, k)


# ------------------------------------------------------------------ one colour per filter
def test_reproduce_curves_take_the_compare_colour_and_label_of_each_filter(outcome):
    for name, df in outcome.curves.items():
        fig = RP.curve_figure(outcome, name)
        keys = [c.partition("_rmse_")[0] for c in df.columns if c != "t_s"]
        compare = {
            t.legendgroup: (t.line.color, t.name)
            for t in F.error_vs_time(run_experiment(ExperimentSpec(runs=2, epochs=5)), "pos").data
            if t.showlegend is not False
        }
        colours = filter_colors()
        assert [t.line.color for t in fig.data] == [colours[k] for k in keys]
        for k, t in zip(keys, fig.data, strict=True):
            if k in compare:  # the same colour as on Compare
                assert t.line.color == compare[k][0]
        lay = _d(fig)
        assert lay["yaxis"]["title"]["text"] == "RMSE (m)" and lay["xaxis"]["title"]["text"] == "time (s)"
        assert_legend_below(fig)


def test_reproduce_claims_title_fits_on_a_phone(outcome):
    """The claims chart's title was one 110-character line, cut off at 390 px."""
    title = _d(RP.claims_figure(outcome))["title"]["text"]
    first = title.split("<br>")[0]
    assert len(first) <= 45


# -------------------------------------------------------------------------- Learn, Real data
def test_learn_overview_log_panels_have_clean_ticks_and_true_R_on_top():
    res = step_through("sage-husa", TinySpec(epochs=20, noise_scale=3.0))
    fig = overview_figure(res, 4)
    lay = _d(fig)
    assert_clean_log(lay["yaxis2"])
    assert_clean_log(lay["yaxis3"])
    assert lay["yaxis3"]["title"]["text"] == "R (m²)"
    panel3 = [t for t in fig.data if t.yaxis == "y3"]
    assert panel3[-1].name.startswith("true R") and panel3[-1].line.color == TRUTH_COLOR
    assert_legend_below(fig)


def test_real_data_rhat_is_log_with_the_reference_last_and_clean_epochs_setting_the_range(mixture):
    fig = RD.rhat_figure(mixture, 0)
    lay = _d(fig)
    assert (
        lay["yaxis"]["type"] == "log"
        and _d(RD.rhat_figure(mixture, 0, log_y=False))["yaxis"]["type"] == "linear"
    )
    assert fig.data[-1].name == "nominal √R0" and fig.data[-1].line.color == TRUTH_COLOR
    assert_clean_log(lay["yaxis"])
    # the oracle is not a real-data filter, but its R̂ shows the rule: the injected outliers'
    # √R̂ (√400 … √3600 m) is drawn but does not set the top
    oracle = _only(mixture, ("kf", "oracle-kf"))
    lay = _d(RD.rhat_figure(oracle, 0, run=0))
    hi = 10.0 ** lay["yaxis"]["range"][1]
    assert hi < 20 and np.nanmax(np.sqrt(mixture.runs["oracle-kf"].R_hat[0, :, 0])) >= 20


def test_the_old_layout_is_gone(small):
    """Regression: the legend once sat at y = 1.02 over the title (R̂ and NIS charts)."""
    for fig in (F.r_vs_rhat(small, 0), F.nis_vs_chi2(small)):
        lg = _d(fig)["legend"]
        assert not (lg.get("y", 0) > 1 and lg.get("yref", "paper") == "paper")


def test_diverged_stub_keeps_the_layout(small):
    fr = small.runs["chi2-kf"]
    bad = dataclasses.replace(fr, x=np.full_like(fr.x, np.nan), diverged_at=np.zeros(small.data.B, int))
    r = dataclasses.replace(small, runs={**small.runs, "chi2-kf": bad})
    fig = F.r_vs_rhat(r, 0)
    assert _d(fig)["yaxis"]["type"] == "log" and fig.data[-1].name == "true R(t) (schedule)"


def test_the_internals_subtitle_names_a_dashed_threshold_only_when_one_is_drawn():
    """'dashed: the filter's threshold' stood under a VB α chart that has no threshold line."""
    res = run_experiment(ExperimentSpec(runs=3, epochs=20, filters=("vb-akf", "mfukf")))
    alpha = F.internals_vs_time(res, "alpha")
    assert not any(t.line.dash == "dash" for t in alpha.data)
    assert "dashed" not in alpha.layout.title.text
    gamma = F.internals_vs_time(res, "gamma")
    assert any(t.line.dash == "dash" for t in gamma.data)
    assert "dashed: the filter's threshold" in gamma.layout.title.text
