"""One case per example of issue 11 (bad input never gives a traceback, a silent wrong answer or a
partial output), each with the number or message that shows it fixed."""

from __future__ import annotations

import errno
import json
import math
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import yaml
from cli_helpers import (
    assert_rejected,
    compact,
    imu_rows,
    imu_text,
    run,
    tum_rows,
    write_bag,
    write_calibration,
    write_rows,
)

from imuslam.cli.common import write_json
from imuslam.io.load import load_imu, write_imu
from imuslam.io.trajectory import read_euroc_gt
from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg


@pytest.fixture
def imu_txt(tmp_path: Path) -> Path:
    return write_rows(tmp_path / "imu.txt", imu_text(imu_rows()))


@pytest.fixture
def tums(tmp_path: Path) -> tuple[Path, Path]:
    rows = [[f"{v:.6f}" for v in r] for r in tum_rows()]
    return write_rows(tmp_path / "gt.tum", rows), write_rows(tmp_path / "est.tum", rows)


@pytest.fixture(scope="module")
def multipose(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 40-pose calibration log (seed 000's errors), as imu_tk text in m/s^2 and rad/s."""
    rng = np.random.default_rng(11)
    sim = simulate_multipose(sphere_plan_deg(40, rng), rng)
    p = tmp_path_factory.mktemp("mp") / "multipose.txt"
    write_imu(sim.log, p, "imutk")
    return p


# --- option values: each example of the issue ---------------------------------------------------
@pytest.mark.parametrize(
    "args, option",
    [
        (["calibrate", "IMU", "--g", "-9.8"], "--g"),
        (["calibrate", "IMU", "--g", "0"], "--g"),
        (["calibrate", "IMU", "--g", "nan"], "--g"),
        (["calibrate", "IMU", "--g", "inf"], "--g"),
        (["calibrate", "IMU", "--g", "98.1"], "--g"),
        (["calibrate", "IMU", "--t-init", "-5"], "--t-init"),
        (["calibrate", "IMU", "--bias-sign", "foo"], "--bias-sign"),
        (["demo", "--poses", "0"], "--poses"),
        (["demo", "--poses", "-3"], "--poses"),
        (["demo", "--poses", "1"], "--poses"),
        (["online", "--sim", "--poses", "1"], "--poses"),
        (["demo", "--seed", "-1"], "--seed"),
        (["simulate", "room", "--seed", "-1"], "--seed"),
        (["simulate", "room", "--duration", "inf"], "--duration"),
        (["simulate", "room", "--duration", "1e7"], "--duration"),
        (["simulate", "room", "--duration", "0"], "--duration"),
        (["simulate", "moon"], "'scenario'"),
        (["align", "IMU", "--method", "ekf"], "--method"),
        (["eval", "GT", "EST", "--rpe-unit", "km"], "--rpe-unit"),
        (["score", "IMU"], "CALIB"),
        (["eval", "GT", "EST", "--rpe-delta", "0"], "--rpe-delta"),
        (["eval", "GT", "EST", "--rpe-delta", "nan"], "--rpe-delta"),
        (["online", "--sim", "--t-init", "0"], "--t-init"),
        (["online", "--sim", "--duration-h", "-1"], "--duration-h"),
        (["online", "--sim", "--duration-h", "inf"], "--duration-h"),
        (["align", "IMU", "--method", "coarse", "--lat-deg", "120"], "--lat-deg"),
        (["align", "IMU", "--heading-deg", "nan"], "--heading-deg"),
        (["align", "IMU", "--t-still", "-5"], "--t-still"),
    ],
)
def test_option_examples(
    args: list[str], option: str, tmp_path: Path, imu_txt: Path, tums: tuple[Path, Path]
) -> None:
    subst = {"IMU": str(imu_txt), "GT": str(tums[0]), "EST": str(tums[1])}
    r = run([subst.get(a, a) for a in args] + ["--out", str(tmp_path / "out")])
    assert_rejected(r, [option], tmp_path, codes=(2,))


# --- --out ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "command", ["calibrate", "allan", "align", "eval", "simulate", "online", "demo", "correct"]
)
@pytest.mark.parametrize("kind", ["existing file", "under a file"])
def test_out_before_any_work(
    command: str, kind: str, tmp_path: Path, imu_txt: Path, tums: tuple[Path, Path]
) -> None:
    (tmp_path / "afile").write_text("x")
    out = tmp_path / "afile" if kind == "existing file" else tmp_path / "afile" / "o" / "out"
    if command == "correct" and kind == "existing file":
        (tmp_path / "afolder").mkdir()
        out = tmp_path / "afolder"  # a folder where the corrected file is expected
    ins = {"eval": [*tums], "simulate": ["room"], "online": ["--sim"], "demo": [],
           "correct": [imu_txt, "--calib", tmp_path / "missing.yaml"]}.get(command, [imu_txt])  # fmt: skip
    r = run([command, *ins, "--out", out])
    assert_rejected(r, ["--out"], None, codes=(2,))


def _full_disk(after: int):  # type: ignore[no-untyped-def]
    """A write_atomic that fills the disk on its ``after``-th call."""
    from imuslam.io import atomic

    real = atomic.write_atomic
    calls = {"n": 0}

    def write(path: object, data: object) -> None:
        calls["n"] += 1
        if calls["n"] >= after:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, data)  # type: ignore[arg-type]

    return write


@pytest.mark.parametrize("after", [1, 3])
def test_full_disk_leaves_nothing_eval(after: int, tmp_path: Path, tums: tuple[Path, Path]) -> None:
    """eval wrote metrics.json and died on a plot: now the whole set is gone, exit 2 naming --out."""
    targets = ["imuslam.io.results.write_atomic", "imuslam.io.figures.write_atomic",
               "imuslam.io.trajectory.write_atomic"]  # fmt: skip
    fake = _full_disk(after)
    with mock.patch(targets[0], fake), mock.patch(targets[1], fake), mock.patch(targets[2], fake):
        r = run(["eval", *tums, "--out", tmp_path / "out"])
    assert_rejected(r, ["--out"], tmp_path, codes=(2,))
    assert "No space left" in r.output


def test_full_disk_leaves_nothing_calibrate(multipose: Path, tmp_path: Path) -> None:
    """calibrate left calibration.yaml, .calib files, config.yaml and a plot: now nothing."""
    fake = _full_disk(5)
    with (
        mock.patch("imuslam.imu.model.write_atomic", fake),
        mock.patch("imuslam.config.write_atomic", fake),
        mock.patch("imuslam.io.figures.write_atomic", fake),
    ):
        # one fit, no cross-validation: the fits come before any write and are not what is tested here
        r = run(["calibrate", multipose, "--method", "tedaldi", "--cv-folds", "0",
                 "--out", tmp_path / "out"])  # fmt: skip
    assert_rejected(r, ["--out"], tmp_path, codes=(2,))


def test_full_disk_into_existing_folder_keeps_it(tmp_path: Path, tums: tuple[Path, Path]) -> None:
    """An existing results folder keeps what it had when a run into it fails."""
    out = tmp_path / "out"
    assert run(["eval", *tums, "--out", out]).exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    (out / "mine.txt").write_text("keep")
    with mock.patch("imuslam.io.figures.write_atomic", _full_disk(1)):
        r = run(["eval", *tums, "--align", "sim3", "--out", out])
    assert r.exit_code == 2
    after = {p.name: p.read_bytes() for p in out.iterdir()}
    assert after.pop("mine.txt") == b"keep" and after == before


# --- bytes that are not text, near-valid files ----------------------------------------------------
def test_random_bytes_and_utf16(tmp_path: Path, imu_txt: Path) -> None:
    rand = tmp_path / "rand.csv"
    rand.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    for args in (["calibrate", rand], ["eval", rand, rand]):
        assert_rejected(run([*args, "--out", tmp_path / "out"]), ["rand.csv"], tmp_path, codes=(2,))
    u16 = tmp_path / "u16.txt"
    u16.write_bytes(imu_txt.read_text().encode("utf-16"))  # with its BOM, as Windows writes it
    a, b = load_imu(u16, accel_unit="m/s^2", gyro_unit="rad/s"), load_imu(imu_txt)
    np.testing.assert_array_equal(a.t_ns, b.t_ns)
    np.testing.assert_array_equal(a.accel, b.accel)
    calib = tmp_path / "cal.yaml"
    calib.write_bytes(bytes(range(256)))
    r = run(["correct", imu_txt, "--calib", calib, "--out", tmp_path / "out.txt"])
    assert_rejected(r, ["cal.yaml"], tmp_path, codes=(2,))


def test_euroc_ground_truth_with_spaces(tmp_path: Path) -> None:
    """Separated by spaces it reads exactly as with commas (the stamps as integers)."""
    rows = tum_rows()
    body = [[str(1403636579758555392 + int(5e6) * i)] + [f"{v:.6f}" for v in r[1:4]]
            + [f"{r[7]:.6f}"] + [f"{v:.6f}" for v in r[4:7]] for i, r in enumerate(rows)]  # fmt: skip
    comma, space = tmp_path / "c.csv", tmp_path / "s.csv"
    comma.write_text("#timestamp,x,y,z,qw,qx,qy,qz\n" + "".join(",".join(b) + "\n" for b in body))
    space.write_text("#timestamp x y z qw qx qy qz\n" + "".join(" ".join(b) + "\n" for b in body))
    a, b = read_euroc_gt(comma), read_euroc_gt(space)
    assert a.t_ns[0] == 1403636579758555392
    np.testing.assert_array_equal(a.t_ns, b.t_ns)
    np.testing.assert_array_equal(a.p_w, b.p_w)
    r = run(["eval", comma, space, "--format", "euroc", "--out", tmp_path / "out"])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "out" / "metrics.json").read_text())["ape_trans"]["max"] < 1e-9


def test_ragged_imutk_row(tmp_path: Path) -> None:
    rows = imu_text(imu_rows())
    rows[17] += ["0.1", "0.2", "0.3"]  # one 10-column row among 7-column rows
    log = write_rows(tmp_path / "imu.txt", rows)
    r = run(["calibrate", log, "--out", tmp_path / "out"])
    assert_rejected(r, ["imu.txt, line 18"], tmp_path, codes=(2,))
    assert "10 columns" in r.output


def test_euroc_stamp_beyond_int64(tmp_path: Path) -> None:
    rows = imu_rows()
    lines = [f"{1403636579758555392 + 5_000_000 * i},{','.join(f'{v:.6f}' for v in r[4:7])},"
             f"{','.join(f'{v:.6f}' for v in r[1:4])}" for i, r in enumerate(rows)]  # fmt: skip
    lines[9] = "99999999999999999999" + lines[9][19:]
    p = tmp_path / "data.csv"
    p.write_text(
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_y,w_z,a_x,a_y,a_z\n" + "\n".join(lines) + "\n"
    )
    r = run(["allan", p, "--out", tmp_path / "out"])
    assert_rejected(r, ["data.csv, line 11"], tmp_path, codes=(2,))
    assert "int64" in r.output


@pytest.mark.parametrize(
    "field, value, named",
    [
        ("units", "counts", "'units'"),
        ("accel", [1, 2, 3], "'accel'"),
        ("g", "abc", "'g'"),
        ("units", {"accel_in": "furlongs"}, "units.accel_in"),
    ],
)
def test_calibration_field_types(
    field: str, value: object, named: str, tmp_path: Path, imu_txt: Path
) -> None:
    cal = write_calibration(tmp_path / "cal.yaml")
    doc = yaml.safe_load(cal.read_text())
    doc[field] = value
    cal.write_text(yaml.safe_dump(doc))
    r = run(["correct", imu_txt, "--calib", cal, "--out", tmp_path / "out.txt"])
    assert_rejected(r, [named], tmp_path, codes=(2,))
    assert "--accel-unit" not in r.output  # a calibration file's field is not blamed on an option


# --- bag contents -------------------------------------------------------------------------------
@pytest.mark.parametrize("value", [math.nan, math.inf])
@pytest.mark.parametrize("command", ["allan", "align"])
def test_nonfinite_sample_in_bag(command: str, value: float, tmp_path: Path) -> None:
    rows = imu_rows(2000)
    rows[1234, 5] = value
    bag = write_bag(tmp_path / "imu.mcap", rows)
    r = run([command, bag, "--out", tmp_path / "out"])
    assert_rejected(r, ["imu.mcap"], tmp_path, codes=(2,))
    assert "sample 1234" in r.output and "NaN or infinite" in r.output


def test_mcap_corrupted_in_the_middle(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "imu.mcap", imu_rows(2000))
    raw = bytearray(bag.read_bytes())
    k = len(raw) // 2
    raw[k : k + 2000] = b"\xff" * 2000
    bag.write_bytes(bytes(raw))
    r = run(["allan", bag, "--out", tmp_path / "out"])
    assert_rejected(r, ["imu.mcap"], tmp_path, codes=(2,))
    assert "corrupted" in r.output or "cannot open" in r.output


@pytest.mark.parametrize("mutation", ["backwards", "repeats"])
def test_eval_time_order(mutation: str, tmp_path: Path, tums: tuple[Path, Path]) -> None:
    rows = [[f"{v:.6f}" for v in r] for r in tum_rows()]
    rows[20][0] = rows[19][0] if mutation == "repeats" else rows[10][0]
    est = write_rows(tmp_path / "est.tum", rows)
    r = run(["eval", tums[0], est, "--out", tmp_path / "out"])
    assert_rejected(r, ["est.tum, line 21"], tmp_path, codes=(2,))
    assert ("repeats" if mutation == "repeats" else "backwards") in r.output


def test_no_infinity_in_json(tmp_path: Path) -> None:
    write_json(tmp_path / "m.json", {"a": math.inf, "b": [math.nan, 1.0], "c": np.float64(-np.inf)})

    def refuse(name: str) -> None:
        raise AssertionError(f"{name} in JSON")

    d = json.loads((tmp_path / "m.json").read_text(), parse_constant=refuse)
    assert d == {"a": None, "b": [None, 1.0], "c": None}


# --- silent wrong answers -------------------------------------------------------------------------
def test_correct_counts_calibration_on_si_log(tmp_path: Path, imu_txt: Path) -> None:
    """A calibration for raw counts applied to a log in m/s^2 wrote about -79 m/s^2 with exit 0."""
    cal = write_calibration(tmp_path / "cal.yaml", "counts", "counts")
    r = run(["correct", imu_txt, "--calib", cal, "--out", tmp_path / "out.txt"])
    assert_rejected(r, ["imu.txt"], tmp_path, codes=(2,))
    assert "accel_in" in r.output and "counts" in r.output


def test_gyro_in_degrees_declared_radians(multipose: Path, tmp_path: Path) -> None:
    d = np.loadtxt(multipose)
    d[:, 4:7] = np.rad2deg(d[:, 4:7])
    p = tmp_path / "deg.txt"
    np.savetxt(p, d, fmt="%.9g")
    r = run(
        ["calibrate", p, "--accel-unit", "m/s^2", "--gyro-unit", "rad/s", "--out", tmp_path / "out"]
    )
    assert_rejected(r, ["--gyro-unit"], tmp_path, codes=(2,))
    assert "deg/s" in r.output and "0.01" in r.output  # the scale it would have reported: pi/180
    ok = run(["calibrate", p, "--accel-unit", "m/s^2", "--gyro-unit", "deg/s", "--method", "tedaldi", "--cv-folds", "0",
              "--no-plots", "--out", tmp_path / "ok"])  # fmt: skip
    assert ok.exit_code == 0, ok.output


def test_allan_counts_and_short_log(tmp_path: Path) -> None:
    """No Kalibr imu.yaml in counts; a random walk the log is too short to show is a finite bound."""
    rng = np.random.default_rng(3)
    n = 3000
    t = np.arange(n) * 0.01
    counts = np.column_stack([t, rng.normal(0, 8, (n, 3)) + [0, 0, 2048], rng.normal(0, 3, (n, 3))])
    p = tmp_path / "counts.txt"
    np.savetxt(p, counts)
    r = run(
        ["allan", p, "--accel-unit", "counts", "--gyro-unit", "counts", "--out", tmp_path / "a"]
    )
    assert r.exit_code == 0, r.output
    assert not (tmp_path / "a" / "imu.yaml").exists()
    assert "imu.yamlnotwritten" in compact(r.output)
    si = counts.copy()
    si[:, 1:4] *= 9.80665 / 2048
    si[:, 4:7] *= 1e-3
    np.savetxt(p, si)
    r = run(["allan", p, "--accel-unit", "m/s^2", "--gyro-unit", "rad/s", "--out", tmp_path / "b"])
    assert r.exit_code == 0, r.output
    k = yaml.safe_load((tmp_path / "b" / "imu.yaml").read_text())
    assert all(
        math.isfinite(v) and v > 0 for key, v in k.items() if key.endswith(("walk", "density"))
    )
    assert "upperbound" in compact(r.output)


def test_allan_moving_log(tmp_path: Path) -> None:
    rows = imu_rows(3000)
    ang = np.linspace(0, np.pi / 2, 3000)  # turned by 90 deg during the log
    rows[:, 1], rows[:, 3] = 9.81 * np.sin(ang), 9.81 * np.cos(ang)
    p = write_rows(tmp_path / "moving.txt", imu_text(rows))
    r = run(["allan", p, "--out", tmp_path / "out"])
    assert_rejected(r, ["moving.txt"], tmp_path, codes=(2,))
    assert "not a static log" in r.output


# --- bag paths ------------------------------------------------------------------------------------
def test_mcap_path_is_read_as_given(tmp_path: Path) -> None:
    """A .mcap beside another bag's metadata.yaml is read as itself, and standalone it is readable."""
    a = write_bag(tmp_path / "other" / "a.mcap", imu_rows(300, seed=1))
    write_bag(tmp_path / "other_bag", imu_rows(300, seed=2))  # a ROS 2 folder with metadata.yaml
    b_dir = tmp_path / "other_bag"
    mine = b_dir / "mine.mcap"
    mine.write_bytes(a.read_bytes())
    got = load_imu(mine)
    np.testing.assert_allclose(got.accel, imu_rows(300, seed=1)[:, 1:4])
    np.testing.assert_allclose(load_imu(a).gyro, imu_rows(300, seed=1)[:, 4:7])


def test_correct_out_mcap_is_a_file(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "raw.mcap", imu_rows(300))
    assert bag.is_file()
    cal = write_calibration(tmp_path / "cal.yaml")
    r = run(["correct", bag, "--calib", cal, "--out", tmp_path / "fixed.mcap"])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "fixed.mcap").is_file()
    fixed = load_imu(tmp_path / "fixed.mcap")
    np.testing.assert_allclose(fixed.accel, (imu_rows(300)[:, 1:4] + 0.01) * 1.01, rtol=1e-12)


# --- messages that misled -------------------------------------------------------------------------
def test_sim3_of_a_motionless_estimate(tmp_path: Path, tums: tuple[Path, Path]) -> None:
    rows = [[f"{v:.6f}" for v in r] for r in tum_rows(still=True)]
    est = write_rows(tmp_path / "still.tum", rows)
    r = run(["eval", tums[0], est, "--align", "sim3", "--out", tmp_path / "out"])
    assert_rejected(r, ["still.tum"], tmp_path, codes=(3,))
    assert "do not move" in r.output and "NaN" not in r.output


def test_one_absurd_value_names_its_line(tmp_path: Path) -> None:
    rows = imu_text(imu_rows())
    rows[41][2] = "1e308"
    log = write_rows(tmp_path / "imu.txt", rows)
    r = run(["calibrate", log, "--out", tmp_path / "out"])
    assert_rejected(r, ["imu.txt, line 42"], tmp_path, codes=(2,))
    assert "static intervals" not in r.output


def test_online_imu_port_without_hw_extra(tmp_path: Path) -> None:
    with mock.patch.dict("sys.modules", {"smbus2": None, "serial": None}):
        r = run(["online", "--imu-port", "/dev/ttyUSB0", "--out", tmp_path / "out"])
    assert_rejected(r, ["--imu-port"], tmp_path, codes=(2,))
    assert "imuslam[hw]" in r.output


# --- also -----------------------------------------------------------------------------------------
def test_align_csv_with_columns_and_units(tmp_path: Path) -> None:
    rows = imu_rows(1500)
    p = tmp_path / "log.csv"
    body = "".join(f"{r[0]:.4f},{r[1] / 9.80665:.7f},{r[2] / 9.80665:.7f},{r[3] / 9.80665:.7f},"
                   f"{np.rad2deg(r[4]):.6f},{np.rad2deg(r[5]):.6f},{np.rad2deg(r[6]):.6f}\n" for r in rows)  # fmt: skip
    p.write_text("time,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\n" + body)
    r = run(["align", p, "--format", "csv", "--columns",
             "t=time,ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z",
             "--accel-unit", "g", "--gyro-unit", "deg/s", "--method", "coarse", "--out", tmp_path / "out"])  # fmt: skip
    assert r.exit_code == 0, r.output
    a = json.loads((tmp_path / "out" / "metrics.json").read_text())
    # level within the noise: 0.02 m/s^2 over 500 samples of 9.81 -> ~5e-5 rad
    assert abs(a["roll"]) < 1e-3 and abs(a["pitch"]) < 1e-3


def test_unknown_config_key_named(tmp_path: Path, imu_txt: Path) -> None:
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("g: 9.81\nwindow_sec: 2\n")
    r = run(["calibrate", imu_txt, "--config", cfg, "--out", tmp_path / "out"])
    assert_rejected(r, ["window_sec"], tmp_path, codes=(2,))
    assert "window_s" in r.output  # the keys it has, to spot the typo
