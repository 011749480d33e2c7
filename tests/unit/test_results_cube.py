"""The result cube: Results.to_xarray(), navlab run --save-results FILE.nc, navlab.load_results."""

from __future__ import annotations

import json

import numpy as np
import pytest
import xarray as xr

import navlab
from navlab.cli import main
from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec, run_experiment, save_results

SPEC = ExperimentSpec(
    scenario="cv2d", filters=("kf", "sage-husa", "chi2-kf"), runs=6, epochs=25, seed=4, noise_schedule="step"
)


@pytest.fixture(scope="module")
def res():
    return run_experiment(SPEC)


def test_the_cube_holds_truth_estimates_rhat_flags_and_the_spec(res):
    ds = res.to_xarray()
    assert dict(ds.sizes) == {"filter": 3, "run": 6, "epoch": 26, "channel": 2, "state": 4}
    assert list(ds["filter"].values) == ["kf", "sage-husa", "chi2-kf"]
    assert ds["x"].dims == ("filter", "run", "epoch", "state")
    np.testing.assert_array_equal(ds["x"].sel(filter="sage-husa").values, res.runs["sage-husa"].x)
    np.testing.assert_array_equal(ds["x_true"].values, res.data.x_true)
    np.testing.assert_array_equal(ds["flags"].sel(filter="chi2-kf").values, res.runs["chi2-kf"].flags)
    np.testing.assert_array_equal(ds["R_hat"].sel(filter="sage-husa").values, res.runs["sage-husa"].R_hat)
    assert np.isnan(ds["R_hat"].sel(filter="kf")).all()  # the KF does not estimate R
    np.testing.assert_array_equal(ds["R_schedule"].values, res.data.R_schedule)
    assert ds.attrs["navlab_version"] == navlab.__version__
    assert ExperimentSpec.from_dict(json.loads(ds.attrs["spec"])) == SPEC


def test_a_saved_file_loads_back_equal(res, tmp_path):
    path = tmp_path / "r.nc"
    save_results(res, path)
    back = navlab.load_results(path)
    xr.testing.assert_identical(back, res.to_xarray())
    assert back["flags"].dtype == np.int8 and back["diverged_at"].dtype == np.int32


def test_cli_save_results(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("NAVLAB_STORE", str(tmp_path / "store"))
    path = tmp_path / "cli.nc"
    argv = ["run", "--scenario", "cv2d", "--filters", "kf,huber-kf", "--runs", "4", "--epochs", "10", "-q"]
    assert main([*argv, "--save-results", str(path)]) == 0
    ds = navlab.load_results(path)
    assert list(ds["filter"].values) == ["kf", "huber-kf"] and ds.sizes["run"] == 4
    assert main([*argv, "--summary", "--save-results", str(path)]) == 2
    assert "--summary drops" in capsys.readouterr().err


def test_load_results_says_what_is_wrong(tmp_path):
    with pytest.raises(NavlabError, match="no results file"):
        navlab.load_results(tmp_path / "missing.nc")
    bad = tmp_path / "bad.nc"
    bad.write_text("not netcdf")
    with pytest.raises(NavlabError, match="not a netCDF results file"):
        navlab.load_results(bad)
    other = tmp_path / "other.nc"
    xr.Dataset({"a": ("x", np.arange(3.0))}).to_netcdf(other, engine="scipy")
    with pytest.raises(NavlabError, match="not navlab results"):
        navlab.load_results(other)
    damaged = tmp_path / "damaged.nc"  # loaded, but json.loads(ds.attrs["spec"]) then raised
    xr.Dataset({"a": ("x", np.arange(3.0))}, attrs={"spec": "{broken", "navlab_version": "0"}).to_netcdf(
        damaged, engine="scipy"
    )
    with pytest.raises(NavlabError, match="a damaged results file"):
        navlab.load_results(damaged)
