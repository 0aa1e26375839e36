"""``imuslam vio`` end to end and its bad inputs: each a one-line error (exit 2) and no results folder, or
a counted warning (missing, unreadable, featureless frames)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from imuslam.cli import app

EUROC = "euroc_V1_01_micro_kimera"


def _copy(shared: Path, dst: Path, n: int) -> Path:
    """The first ``n`` stereo pairs of the excerpt (and its IMU) under ``dst/mav0``."""
    src = shared / EUROC / "mav0"
    root = dst / "mav0"
    for cam in ("cam0", "cam1"):
        (root / cam / "data").mkdir(parents=True)
        shutil.copy(src / cam / "sensor.yaml", root / cam / "sensor.yaml")
        lines = [
            x for x in (src / cam / "data.csv").read_text().splitlines() if not x.startswith("#")
        ][:n]
        (root / cam / "data.csv").write_text("#timestamp [ns],filename\n" + "\n".join(lines) + "\n")
        for x in lines:
            shutil.copy(src / cam / "data" / x.split(",")[1], root / cam / "data")
    (root / "imu0").mkdir()
    imu = (src / "imu0" / "data.csv").read_text().splitlines()
    (root / "imu0" / "data.csv").write_text("\n".join(imu[:2000]) + "\n")
    return dst


def _run(*args: str) -> tuple[int, str]:
    r = CliRunner().invoke(app, ["vio", *args])
    return r.exit_code, r.output


def test_cli_writes_the_results_folder_and_counts_bad_frames(
    shared_data: Path, tmp_path: Path
) -> None:
    import cv2

    d = _copy(shared_data, tmp_path / "ds", 14)
    left = sorted((d / "mav0" / "cam0" / "data").iterdir())
    left[5].write_bytes(b"\x89PNG broken")  # unreadable: skipped and counted
    blank = np.full((480, 752), 128, np.uint8)  # no texture: too few features, skipped and counted
    cv2.imwrite(str(left[9]), blank)
    cv2.imwrite(str(d / "mav0" / "cam1" / "data" / left[9].name), blank)
    out = tmp_path / "out"
    code, text = _run(str(d), "--out", str(out), "--g", "9.81")
    assert code == 0, text
    for f in (
        "trajectory.tum",
        "vo.tum",
        "imu.tum",
        "metrics.json",
        "config.yaml",
        "tracks.png",
        "nis.png",
    ):
        assert (out / f).is_file(), f
    g = json.loads((out / "metrics.json").read_text())
    assert g["frames"]["unreadable"] == 1
    assert g["vo"]["skipped_few_features"] + g["vo"]["skipped_few_inliers"] >= 1
    assert "1 unreadable" in text
    # the closing line names every file the folder holds (metrics.json included)
    wrote = "".join(text[text.index("wrote ") :].split())  # wrapped at 80 columns
    for f in ("trajectory.tum", "vo.tum", "imu.tum", "metrics.json", "config.yaml"):
        assert f in wrote, f


@pytest.mark.parametrize(
    "case, pattern",
    [
        ("no_cam1", r"no cam1 folder; stereo VO needs the second camera"),
        ("camchain_one_camera", r"no 'cam1' entry; a stereo camchain needs cam0 and cam1"),
        ("size", r"image is 376x240; the calibration .* says 752x480"),
        ("no_imu", r"no IMU samples in the image time span"),
        ("all_blank", r"no VO measurement from 6 frames \(0 unreadable, 5 with too few features"),
        ("all_unreadable", r"no VO measurement from 6 frames \(6 unreadable"),
        ("all_missing", r"none of the 6 listed stereo pairs exists on disk"),
        ("no_imu_file", r"imu0/data.csv"),
        ("calib_without_cam1", r"cam1/sensor.yaml"),
        ("bad_config", r"config.yaml: .*nhc_std"),
        ("config_across_fields", r"config.yaml: vo_error_std applies to vo_model 'rate' only"),
        ("config_adapt_hold_alone", r"config.yaml: vo_cov_adapt_s .* needs vo_cov_adapt_n > 0"),
        ("bag_without_camchain", r"a bag needs --camchain, --left-topic and --right-topic"),
    ],
)
def test_bad_inputs_are_one_line_errors(
    shared_data: Path, tmp_path: Path, case: str, pattern: str
) -> None:
    import cv2

    d = _copy(shared_data, tmp_path / "ds", 6)
    args = [str(d)]
    m = d / "mav0"
    if case == "no_cam1":
        shutil.rmtree(m / "cam1")
    elif case == "camchain_one_camera":
        p = tmp_path / "camchain.yaml"
        p.write_text(
            yaml.safe_dump(
                {
                    "cam0": {
                        "intrinsics": [458.0, 457.0, 367.0, 248.0],
                        "resolution": [752, 480],
                        "T_cam_imu": np.eye(4).tolist(),
                    }
                }
            )
        )
        args += ["--camchain", str(p)]
    elif case == "size":
        f = sorted((m / "cam1" / "data").iterdir())[2]
        cv2.imwrite(str(f), np.zeros((240, 376), np.uint8))
    elif case == "no_imu":
        rows = (m / "imu0" / "data.csv").read_text().splitlines()
        (m / "imu0" / "data.csv").write_text("\n".join([rows[0]] + [
            ",".join([str(int(r.split(",")[0]) + 10**12)] + r.split(",")[1:]) for r in rows[1:]
        ]) + "\n")  # fmt: skip
    elif case == "all_blank":
        for cam in ("cam0", "cam1"):
            for f in (m / cam / "data").iterdir():
                cv2.imwrite(str(f), np.full((480, 752), 100, np.uint8))
    elif case == "all_unreadable":
        for f in (m / "cam0" / "data").iterdir():
            f.write_bytes(b"\x89PNG truncated")
    elif case == "all_missing":
        for f in (m / "cam1" / "data").iterdir():
            f.unlink()
    elif case == "no_imu_file":
        (m / "imu0" / "data.csv").unlink()
    elif case == "calib_without_cam1":
        (m / "cam1" / "sensor.yaml").unlink()
    elif case == "bag_without_camchain":
        (tmp_path / "x.mcap").write_bytes(b"")
        args = [str(tmp_path / "x.mcap")]
    elif case == "bad_config":
        p = tmp_path / "config.yaml"
        p.write_text("nhc_std: -1\n")
        args += ["--config", str(p)]
    elif case == "config_across_fields":
        p = tmp_path / "config.yaml"
        p.write_text("vo_model: relative\nvo_error_std: 0.001\n")
        args += ["--config", str(p)]
    elif case == "config_adapt_hold_alone":
        p = tmp_path / "config.yaml"
        p.write_text("vo_cov_adapt_s: 30\n")
        args += ["--config", str(p)]
    out = tmp_path / "out"
    code, text = _run(*args, "--out", str(out))
    assert code == 2, text
    assert "Traceback" not in text
    import re

    assert re.search(pattern, " ".join(text.split())), text
    assert not out.exists()


def test_cli_reports_the_online_covariance_scales(shared_data: Path, tmp_path: Path) -> None:
    """With ``vo_cov_adapt_n`` in the config, metrics.json carries the learnt scales. On this excerpt the
    MAV stands still and the front end's covariance over-states the VO's error (mean NIS well below 3
    with the scales fixed), so both scales must come out below one."""
    d = _copy(shared_data, tmp_path / "ds", 14)
    fixed, adapt = tmp_path / "fixed", tmp_path / "adapt"
    assert _run(str(d), "--out", str(fixed), "--g", "9.81")[0] == 0
    g0 = json.loads((fixed / "metrics.json").read_text())
    assert "vo_cov_adapted_scale" not in g0
    assert g0["gating"]["vo_velocity"]["nis_mean_accepted"] < 1.5
    assert g0["gating"]["vo_rate"]["nis_mean_accepted"] < 1.5
    cfg = tmp_path / "config.yaml"
    cfg.write_text("vo_cov_adapt_n: 10\n")
    code, text = _run(str(d), "--out", str(adapt), "--g", "9.81", "--config", str(cfg))
    assert code == 0, text
    s = json.loads((adapt / "metrics.json").read_text())["vo_cov_adapted_scale"]
    print(s)
    assert 0.05 <= s["rate"] < 1.0 and 0.05 <= s["velocity"] < 1.0


def test_example_config_sets_the_front_end(tmp_path: Path) -> None:
    """``examples/vio_every_frame.yaml`` loads through ``--config`` and its nested front-end setting
    reaches the run: the written ``config.yaml`` has it, and each frame starts from more tracks. With the
    default 0.7 a frame's tracks run down from 300 towards 210 before the detector refills them; with
    the detector on every frame that lost a track they start near 300 each time, so the mean count of
    tracked features must rise (on 3 s of the rendered robot: about 235 against 274)."""
    example = Path(__file__).resolve().parents[2] / "examples" / "vio_every_frame.yaml"
    tracked = {}
    for name, extra in (("default", []), ("every", ["--config", str(example)])):
        code, text = _run("sim", "--sim-duration", "3", "--out", str(tmp_path / name), *extra)
        assert code == 0, text
        written = yaml.safe_load((tmp_path / name / "config.yaml").read_text())
        assert written["vo"]["redetect_below"] == (1.0 if name == "every" else 0.7)
        vo = json.loads((tmp_path / name / "metrics.json").read_text())["vo"]
        tracked[name] = vo["mean_tracked"]
        # where the front end's time went, by part (no timing is asserted: only that each part is there)
        parts = vo["ms_per_frame"]
        assert set(parts) == {"images", "track", "motion", "detect", "stereo"}
        assert all(np.isfinite(x) and x > 0 for x in parts.values()), parts
    assert tracked["every"] > 1.1 * tracked["default"]
