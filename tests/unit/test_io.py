"""navlab's one decoding path (navlab.io): BOM, binary, non-UTF-8, huge and deeply nested JSON —
in the loaders, the CLI's --config and the app's configuration upload; and which server folders a
configuration loaded in the browser may name."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from navlab.cli import main
from navlab.data.loaders import check_offered, data_root, is_offered, load_generic
from navlab.errors import NavlabError
from navlab.experiment import ExperimentSpec
from navlab.io import decode_text, json_depth, parse_json, read_text

ROOT = Path(__file__).resolve().parents[2]


def _imu_csv(n: int = 200) -> str:
    rows = "\n".join(f"{0.01 * i:.2f},0.01,0.02,9.81,0.001,0.0,0.0" for i in range(n))
    return "t_s,f_x_mps2,f_y_mps2,f_z_mps2,w_x_radps,w_y_radps,w_z_radps\n" + rows + "\n"


GNSS_CSV = "t_s,lat_deg,lon_deg,h_m\n0,40,-105,1600\n1,40,-105,1600\n2,40,-105,1600\n"


def test_a_spreadsheet_saved_imu_csv_with_a_bom_loads(tmp_path):
    (tmp_path / "imu.csv").write_bytes(b"\xef\xbb\xbf" + _imu_csv().replace("\n", "\r\n").encode())
    (tmp_path / "gnss.csv").write_bytes(b"\xef\xbb\xbf" + GNSS_CSV.encode())
    rec = load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv")
    assert len(rec.imu) == 200 and rec.imu.f_z_mps2.iloc[0] == pytest.approx(9.81)


def test_quoted_header_loads_and_semicolons_are_explained(tmp_path):
    text = _imu_csv().splitlines()
    text[0] = ",".join(f'"{c}"' for c in text[0].split(","))
    (tmp_path / "imu.csv").write_text("\n".join(text) + "\n")
    (tmp_path / "gnss.csv").write_text(GNSS_CSV)
    assert len(load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv").imu) == 200
    (tmp_path / "gnss.csv").write_text(GNSS_CSV.replace(",", ";"))
    with pytest.raises(NavlabError, match=r"gnss.csv: line 1 \(header\) separates columns with ';'"):
        load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv")


@pytest.mark.parametrize(
    ("raw", "words"),
    [
        ("t_s,f_x\n1,2\n".encode("utf-16"), "UTF-16 text, not UTF-8; save it as UTF-8"),
        (b"PK\x03\x04\x14\x00\x00\x00\x08\x00", "binary file, not text"),
        ("t_s,h_m\n# Höhe\n".encode("latin-1"), "line 2 is not UTF-8 text (byte 0xf6"),
    ],
)
def test_non_utf8_and_binary_files_are_refused_with_their_name(tmp_path, raw, words):
    (tmp_path / "imu.csv").write_bytes(raw)
    (tmp_path / "gnss.csv").write_text(GNSS_CSV)
    with pytest.raises(NavlabError, match=r"imu\.csv: ") as e:
        load_generic(tmp_path / "imu.csv", tmp_path / "gnss.csv")
    assert words in str(e.value)
    with pytest.raises(NavlabError, match=r"^uploaded imu.csv: "):
        decode_text(raw, "uploaded imu.csv")


def test_read_text_refuses_folders_missing_and_oversized_files(tmp_path):
    with pytest.raises(NavlabError, match="a folder, not a file"):
        read_text(tmp_path)
    with pytest.raises(NavlabError, match="file not found"):
        read_text(tmp_path / "nope.csv")
    (tmp_path / "big.csv").write_text("x" * 5000)
    with pytest.raises(NavlabError, match="more than the"):
        read_text(tmp_path / "big.csv", max_bytes=1000)


def test_json_depth_ignores_brackets_inside_strings():
    assert json_depth('{"a": [1, {"b": "[[[{{"}], "c": "\\"]["}') == 3
    assert json_depth("[" * 1000 + "]" * 1000) == 1000
    assert json_depth("") == 0


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("[" * 100_000, "nests JSON arrays/objects 100000 levels deep"),
        ('{"runs": 5, "filters": ["kf"', "not valid JSON (line 1"),
        ('{"seed": ' + "9" * 5000 + "}", "not a usable JSON document"),
        ('{"a": "' + "x" * (2**20 + 10) + '"}', "kB of JSON, more than"),
    ],
)
def test_bad_json_is_a_navlab_error(text, words):
    with pytest.raises(NavlabError, match="the configuration") as e:
        ExperimentSpec.from_json(text)
    assert words in str(e.value)


def test_parse_json_strips_a_bom():
    assert parse_json(b'\xef\xbb\xbf{"runs": 3}') == {"runs": 3}
    assert ExperimentSpec.from_json('\ufeff{"runs": 3}').runs == 3


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b"[" * 100_000, "levels deep"),
        ('{"runs": 5, "scenario": "cv2d", "note": "Größe"}'.encode("latin-1"), "not UTF-8 text"),
        ("{}".encode("utf-16"), "UTF-16"),
        (b"\x89PNG\r\n\x1a\n\x00\x00", "binary file"),
    ],
)
def test_cli_config_errors_exit_2_with_one_line(tmp_path, capsys, content, words):
    cfg = tmp_path / "spec.json"
    cfg.write_bytes(content)
    rc = main(["run", "--config", str(cfg)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert words in err and err.count("\n") == 1 and "Traceback" not in err


def test_cli_nested_config_in_a_fresh_process_exits_2(tmp_path):
    """The very case of the issue: RecursionError and exit 1 before."""
    cfg = tmp_path / "spec.json"
    cfg.write_text("[" * 100_000)
    p = subprocess.run(
        [sys.executable, "-m", "navlab", "run", "--config", str(cfg)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert p.returncode == 2 and "RecursionError" not in p.stderr and p.stderr.count("\n") == 1


def test_browser_config_upload_goes_through_the_same_path():
    from navlab.ui.share import parse_config

    with pytest.raises(NavlabError, match="levels deep"):
        parse_config(b"[" * 100_000)
    with pytest.raises(NavlabError, match="not UTF-8"):
        parse_config(b'{"runs": 3, "x": "\xe9"}')
    assert parse_config(b'\xef\xbb\xbf{"runs": 3}').runs == 3


def test_no_traceback_reaches_the_browser():
    cfg = tomllib.loads((ROOT / ".streamlit" / "config.toml").read_text())
    assert cfg["client"]["showErrorDetails"] in ("type", "none")


# --------------------------------------------------------------------- server folders


def test_only_the_data_root_and_the_sessions_uploads_are_offered(tmp_path, monkeypatch):
    root = tmp_path / "data"
    (root / "rec").mkdir(parents=True)
    up = tmp_path / "navlab-upload-abc"
    up.mkdir()
    monkeypatch.setenv("NAVLAB_DATA", str(root))
    assert data_root() == root
    assert is_offered(root) and is_offered(root / "rec") and is_offered(str(root / "rec" / ".." / "rec"))
    assert not is_offered(tmp_path) and not is_offered(root / ".." / "elsewhere")
    assert not is_offered(up) and is_offered(up / "x", offered=[up])
    (root / "link").symlink_to(tmp_path)  # a link inside the root pointing outside it
    assert not is_offered(root / "link")
    check_offered("", ())
    check_offered(None, ())
    with pytest.raises(NavlabError) as e:
        check_offered("/etc", ())
    assert "/etc" not in str(e.value) and "does not offer" in str(e.value)


def test_an_uploaded_configuration_cannot_name_a_server_folder(tmp_path, monkeypatch):
    from navlab.ui.share import parse_config

    monkeypatch.setenv("NAVLAB_DATA", str(tmp_path / "data"))
    secret = tmp_path / "secret"
    secret.mkdir()
    (secret / "imu.csv").write_text("t_s,top secret\n")
    raw = ExperimentSpec(scenario="drive0708", filters=("kf",), scenario_params={"data_dir": str(secret)})
    with pytest.raises(NavlabError) as e:
        parse_config(raw.to_json().encode())
    assert str(secret) not in str(e.value) and "secret" not in str(e.value)
    # the session's own upload folder is allowed, and so is the data root
    spec = parse_config(raw.to_json().encode(), offered=[secret])
    assert spec.scenario_params["data_dir"] == str(secret)
    ok = raw.replace(scenario_params={"data_dir": str(tmp_path / "data" / "rtkx_drive_0708")})
    assert parse_config(ok.to_json().encode()).scenario == "drive0708"


def test_the_cli_may_still_name_any_folder(tmp_path, capsys):
    rc = main(["run", "--scenario", "drive0708", "--filters", "kf", "--set", f"scenario.data_dir={tmp_path}"])
    err = capsys.readouterr().err
    assert rc == 2 and str(tmp_path) in err  # the local user's own folder is read (and reported)
    assert "does not offer" not in err
