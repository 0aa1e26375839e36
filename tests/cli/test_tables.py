"""Result tables at 80 columns: units in the headers, numbers and names whole (wrapped, never cut);
score's CALIB files checked before the log loads."""

from __future__ import annotations

import io
from pathlib import Path
from types import SimpleNamespace

import pytest
from rich.console import Console
from typer.testing import CliRunner

from imuslam.cli import app

runner = CliRunner()
# imu_tk's parameters on its xsens log (../shared/data/README.md), as imu_tk writes them
XSENS_ACC = ("1 -0.0033593 -0.00890639\n0 1 -0.0213341\n0 0 1\n\n"
             "0.00241278 0 0\n0 0.00242712 0\n0 0 0.00241168\n\n33124.2\n33275.2\n32364.4\n")  # fmt: skip
XSENS_GYRO = ("1 0.00593634 0.00111101\n0.00808812 1 -0.0535569\n0.0253067 -0.0025513 1\n\n"
              "0.000209295 0 0\n0 0.000209899 0\n0 0 0.000209483\n\n32777.1\n32459.8\n32511.8\n")  # fmt: skip


def _column(text: str, i: int, sep: str = "│") -> str:
    """Column ``i``'s text over every line of a table's body (``│``) or header (``┃``), wrapped
    pieces joined."""
    pieces = [ln.split(sep)[i + 1].strip() for ln in text.splitlines() if ln.startswith(sep)]
    return " ".join(p for p in pieces if p)


def _whole(text: str) -> None:
    assert "…" not in text, text
    assert max(len(ln) for ln in text.splitlines()) <= 80, text


def test_eval_table_at_80_columns(shared_data: Path, tmp_path: Path) -> None:
    d = shared_data / "evo_testdata"
    r = runner.invoke(
        app,
        ["eval", str(d / "fr2_desk_groundtruth.txt"), str(d / "fr2_desk_ORB.txt"),
         "--out", str(tmp_path / "ev"), "--no-plots"],
        env={"COLUMNS": "80"},
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    _whole(r.output)
    assert _column(r.output, 0, "┃") == "quantity [unit]"
    first = _column(r.output, 0)
    assert "APE translation [m]" in first and "APE rotation [deg]" in first
    rmse = next(ln for ln in r.output.splitlines() if "APE" in ln).split("│")[2].strip()
    assert float(rmse) > 0  # the number whole


def test_allan_terms_one_unit_per_cell_in_the_headers(monkeypatch: pytest.MonkeyPatch) -> None:
    from imuslam.cli import allan

    buf = io.StringIO()
    monkeypatch.setattr(allan, "console", Console(file=buf, width=80, emoji=False))
    term = SimpleNamespace(white=1.234e-3, white_rel_std=0.012, bias_instability=5.6e-5,
                           bias_instability_tau_s=120.0, random_walk=7.8e-6, random_walk_rel_std=0.3)  # fmt: skip
    res = SimpleNamespace(accel_terms=[term] * 3, gyro_terms=[term] * 3, accel_unit="m/s^2",
                          gyro_unit="rad/s")  # fmt: skip
    allan._print_terms(res)
    text = buf.getvalue()
    _whole(text)
    headers = [_column(text.split("gyro")[0], i, "┃").replace(" ", "") for i in range(5)]
    assert headers == ["term", "whiteN[m/s^2/sqrt(Hz)]", "biasinstabilityB[m/s^2]", "attau[s]",
                       "randomwalkK[m/s^2*sqrt(Hz)]"]  # fmt: skip
    body = [ln for ln in text.splitlines() if ln.startswith("│")]
    assert body and not any("|" in ln or "Hz" in ln for ln in body)  # no unit left in a cell


def test_vio_gating_counts_name_their_unit(monkeypatch: pytest.MonkeyPatch) -> None:
    from imuslam.cli import vio

    buf = io.StringIO()
    monkeypatch.setattr(vio, "console", Console(file=buf, width=80, emoji=False))
    st = {"dof": 3, "accepted": 93, "rejected": 0, "nis_mean_accepted": 0.314,
          "nis_mean_band_95": [2.52, 3.52]}  # fmt: skip
    vio._print_summary({"gating": {"vo_velocity": st}, "frames": {"used": 95, "missing": 4,
                        "unreadable": 0}, "vo": {"measurements": 94, "skipped_few_features": 0,
                        "skipped_few_inliers": 0}})  # fmt: skip
    text = buf.getvalue()
    _whole(text)
    assert "[updates]" in text


def test_score_names_a_missing_calib_before_loading_the_log(
    shared_data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from imuslam.cli import common

    def no_load(*args: object) -> None:
        raise AssertionError("the log was loaded")

    monkeypatch.setattr(common, "load_log", no_load)
    d = shared_data / "imu_tk_xsens"
    (tmp_path / "acc.calib").write_text("1 0 0\n")
    r = runner.invoke(
        app,
        ["score", str(d / "xsens_acc.mat"), "--gyro", str(d / "xsens_gyro.mat"),
         str(tmp_path / "acc.calib"), str(tmp_path / "gyro.calib")],
    )  # fmt: skip
    assert r.exit_code == 2
    err = " ".join(r.output.split())
    assert err.count("error:") == 1 and "Traceback" not in err
    assert f"{tmp_path / 'gyro.calib'}: no such file" in err
    assert "non-numeric" not in err


def test_score_table_at_80_columns(shared_data: Path, tmp_path: Path) -> None:
    folder = tmp_path / "calib_t265_with_a_rather_long_folder_name"
    folder.mkdir()
    (folder / "acc.calib").write_text(XSENS_ACC)
    (folder / "gyro.calib").write_text(XSENS_GYRO)
    d = shared_data / "imu_tk_xsens"
    r = runner.invoke(
        app,
        ["score", str(d / "xsens_acc.mat"), "--gyro", str(d / "xsens_gyro.mat"),
         str(folder / "acc.calib"), str(folder / "gyro.calib"), "--g", "9.81744"],
        env={"COLUMNS": "80"},
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    _whole(r.output)
    headers = [_column(r.output, i, "┃") for i in range(5)]
    assert headers[1:] == ["norm RMS [m/s^2]", "norm worst [m/s^2]", "direction RMS [deg]",
                           "direction worst [deg]"]  # fmt: skip
    assert "calib_t265_with_a_rather_long_folder_name" in _column(r.output, 0).replace(" ", "")
    assert float(_column(r.output, 3)) == pytest.approx(0.5, abs=0.1)  # imu_tk's published figure
