"""One case per example of issue 34 (bad input to lio, vio, map2d, study, score, align and allan): each
gave a traceback, a silent wrong answer (exit 0) or a message naming neither the file nor the option.
Now each is one line naming the file, option, field or unit, exit 2 (3 when every study cell failed),
and nothing written."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_helpers import (
    assert_rejected,
    compact,
    imu_rows,
    imu_text,
    run,
    write_calibration,
    write_rows,
)

from imuslam.interfaces import ImuLog

RANDOM = np.random.default_rng(34).bytes(
    300
)  # not UTF-8: byte 1 is 0xc4 followed by a non-continuation


@pytest.fixture(scope="module")
def lio_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A 3 s simulated street drive (it turns at up to 0.37 rad/s) as a bag: as recorded, with its gyro
    in deg/s, with point_step 4, with every IMU sample or every scan at one stamp."""
    from imuslam.sim import export
    from imuslam.sim.drive import simulate_lidar_drive

    d = simulate_lidar_drive("street", 3.0, seed=5)
    root = tmp_path_factory.mktemp("lio34")

    def write(name: str, imu: ImuLog, step: int | None = None, scans: list | None = None) -> Path:  # type: ignore[type-arg]
        pc = []
        for s in d.scans if scans is None else scans:
            t, msg = export.pointcloud_message(s)
            pc.append((t, "/points", msg if step is None else replace(msg, point_step=step)))
        export.write_bag(root / name, [export.imu_messages(imu), iter(pc)])
        return root / name

    deg = ImuLog(d.imu.t_ns, d.imu.accel, np.rad2deg(d.imu.gyro), "m/s^2", "rad/s", "deg")
    t1 = np.full_like(d.imu.t_ns, d.imu.t_ns[0])
    imu1 = ImuLog(t1, d.imu.accel, d.imu.gyro, "m/s^2", "rad/s", "one stamp")
    scans1 = [replace(s, t_ns=d.scans[0].t_ns) for s in d.scans]
    return {"good": write("good", d.imu), "deg": write("deg", deg), "ps4": write("ps4", d.imu, 4),
            "imu1": write("imu1", imu1), "scan1": write("scan1", d.imu, scans=scans1)}  # fmt: skip


@pytest.fixture(scope="module")
def sim_room(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``imuslam simulate room`` for 3 s: 30 scans, wheel odometry and the IMU (sim.npz)."""
    out = tmp_path_factory.mktemp("room34") / "room"
    r = run(["simulate", "room", "--duration", "3", "--out", out])
    assert r.exit_code == 0, r.output
    return out


def _room_with(sim_room: Path, dst: Path, **change: np.ndarray) -> Path:
    """A copy of the simulated room whose sim.npz has ``change``d arrays."""
    d = dict(np.load(sim_room / "sim.npz"))
    d.update(change)
    dst.mkdir()
    np.savez(dst / "sim.npz", **d)  # type: ignore[arg-type]
    return dst


# --- lio ------------------------------------------------------------------------------------------
def test_lio_point_step_smaller_than_a_point(lio_bags: dict[str, Path], tmp_path: Path) -> None:
    """A PointCloud2 with point_step 4 (its fields span 22 bytes) gave a numpy ValueError traceback."""
    r = run(["lio", lio_bags["ps4"], "--out", tmp_path / "out"])
    assert_rejected(r, ["point_step"], tmp_path, codes=(2,))
    assert "'y'" in r.output  # the first field beyond the point


@pytest.mark.parametrize(
    "text, field",
    [
        ("extrinsic:\n  time_offset_s: .nan\n", "extrinsic.time_offset_s"),  # was a traceback
        (
            "extrinsic:\n  time_offset_s: 1.7e9\n",
            "extrinsic.time_offset_s",
        ),  # an epoch, not an offset
        ("extrinsic:\n  p_i_l: [0, 0, .inf]\n", "extrinsic.p_i_l"),
        ("filter:\n  lidar_std: .inf\n", "filter.lidar_std"),
        ("map:\n  voxel: 1.0e-9\n", "map.voxel"),
        ("frontend:\n  scan_voxel: 1.0e-9\n", "frontend.scan_voxel"),
        ("filter:\n  g: 98.1\n", "filter.g"),
        ("map:\n  max_per_voxel: 100000\n", "map.max_per_voxel"),  # was a MemoryError traceback
        ("frontend:\n  min_range: 200.0\n", "frontend.min_range"),  # beyond max_range: exit 0
    ],
)
def test_lio_config_value_names_its_field(
    text: str, field: str, lio_bags: dict[str, Path], tmp_path: Path
) -> None:
    """.inf or 1e-9 passed validation and failed later (exit 3) naming no field; NaN was a traceback."""
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(text)
    r = run(["lio", lio_bags["good"], "--config", cfg, "--out", tmp_path / "out"])
    assert_rejected(r, [field], tmp_path, codes=(2,))
    assert "cfg.yaml" in compact(r.output)


@pytest.mark.parametrize("n", ["0", "-5", "1"])  # 1: the odometry needs a second scan
def test_lio_max_scans(n: str, lio_bags: dict[str, Path], tmp_path: Path) -> None:
    r = run(["lio", lio_bags["good"], "--max-scans", n, "--out", tmp_path / "out"])
    assert_rejected(r, ["--max-scans"], tmp_path, codes=(2,))


def test_lio_gyro_in_degrees(lio_bags: dict[str, Path], tmp_path: Path) -> None:
    """The same drive with its gyro in deg/s ran to exit 0 (ATE 5.9 m, 94 deg against 0.007 m);
    as recorded, it still runs."""
    r = run(["lio", lio_bags["deg"], "--max-scans", "3", "--out", tmp_path / "out"])
    assert_rejected(r, ["deg/s"], tmp_path, codes=(2,))
    assert "rad/s" in r.output and "deg" in compact(r.output)
    ok = run(["lio", lio_bags["good"], "--max-scans", "3", "--out", tmp_path / "ok"])
    assert ok.exit_code == 0, ok.output


@pytest.mark.parametrize(
    "bag, expect", [("imu1", "share one timestamp"), ("scan1", "1 usable scans")]
)
def test_lio_stamps_shared(
    bag: str, expect: str, lio_bags: dict[str, Path], tmp_path: Path
) -> None:
    """IMU samples, or scans, that all carry one stamp."""
    r = run(["lio", lio_bags[bag], "--out", tmp_path / "out"])
    assert_rejected(r, [bag], tmp_path, codes=(2,))
    assert compact(expect) in compact(r.output)


# --- vio ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "option, value",
    [("--sim-duration", v) for v in ("-1", "nan", "inf", "1e9", "0")]
    + [("--sim-rate", v) for v in ("0", "nan", "1e6")]
    + [("--seed", v) for v in ("-1", str(2**70))]
    + [("--g", "0"), ("--outliers", "1.5")],
)
def test_vio_sim_options(option: str, value: str, tmp_path: Path) -> None:
    """Each was a traceback (--sim-rate 1e6 ran until killed at 300 s); now refused before any work."""
    r = run(["vio", "sim", option, value, "--out", tmp_path / "out"])
    assert_rejected(r, [option], tmp_path, codes=(2,))


def test_vio_sim_too_few_frames(tmp_path: Path) -> None:
    """1 s at 1 Hz: one frame, reported as "1 common times with the estimates" after the run."""
    r = run(["vio", "sim", "--sim-duration", "1", "--sim-rate", "1", "--out", tmp_path / "out"])
    assert_rejected(r, ["--sim-rate"], tmp_path, codes=(2,))
    assert "1 frame" in r.output


@pytest.mark.parametrize(
    "content, expect",
    [
        (b"vo:\n  detector: [sift\n", "line"),  # a YAML syntax error: its line
        (b"just a string\n", "a string"),
        (RANDOM, "not a text file"),
        (b"- 1\n- 2\n", "a list"),
        (b"noise:\n  gyro: .inf\n", "noise.gyro"),
        (b"vo:\n  search_coarse_px: 100000\n", "vo.search_coarse_px"),  # a numba SystemError
        (b"vo:\n  blur_sigma: 1.0e6\n", "vo.blur_sigma"),  # 22 GB and 210 s for 2 s of images
    ],
)
def test_vio_config_file(content: bytes, expect: str, tmp_path: Path) -> None:
    cfg = tmp_path / "cfg.yaml"
    cfg.write_bytes(content)
    r = run(["vio", "sim", "--config", cfg, "--out", tmp_path / "out"])
    assert_rejected(r, ["cfg.yaml"], tmp_path, codes=(2,))
    assert expect in r.output


def _euroc(shared: Path, dst: Path, gyro_scale: float = 1.0, one_stamp: bool = False) -> Path:
    """The first 3 stereo pairs of the EuRoC excerpt and 4 s of its IMU (gyro times ``gyro_scale``;
    every sample at the first one's stamp with ``one_stamp``)."""
    src = shared / "euroc_V1_01_micro_kimera" / "mav0"
    root = dst / "mav0"
    for cam in ("cam0", "cam1"):
        (root / cam / "data").mkdir(parents=True)
        shutil.copy(src / cam / "sensor.yaml", root / cam / "sensor.yaml")
        lines = [x for x in (src / cam / "data.csv").read_text().splitlines() if x[0] != "#"][:3]
        (root / cam / "data.csv").write_text("#timestamp [ns],filename\n" + "\n".join(lines) + "\n")
        for x in lines:
            shutil.copy(src / cam / "data" / x.split(",")[1], root / cam / "data")
    (root / "imu0").mkdir()
    rows = [x.split(",") for x in (src / "imu0" / "data.csv").read_text().splitlines()[1:800]]
    body = [[rows[0][0] if one_stamp else r[0], *(f"{float(v) * gyro_scale:.9g}" for v in r[1:4]),
             *r[4:7]] for r in rows]  # fmt: skip
    (root / "imu0" / "data.csv").write_text(
        "#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n" + "".join(",".join(b) + "\n" for b in body)
    )
    return dst


def test_vio_camchain_and_sensor_yaml_of_random_bytes(shared_data: Path, tmp_path: Path) -> None:
    ds = _euroc(shared_data, tmp_path / "ds")
    chain = tmp_path / "camchain.yaml"
    chain.write_bytes(RANDOM)
    r = run(["vio", ds, "--camchain", chain, "--out", tmp_path / "out"])
    assert_rejected(r, ["camchain.yaml"], tmp_path, codes=(2,))
    (ds / "mav0" / "cam0" / "sensor.yaml").write_bytes(RANDOM)
    r = run(["vio", ds, "--out", tmp_path / "out"])
    assert_rejected(r, ["cam0/sensor.yaml"], tmp_path, codes=(2,))


def test_vio_gyro_in_degrees(shared_data: Path, tmp_path: Path) -> None:
    """EuRoC's drone turns at up to 0.9 rad/s here; the same IMU in deg/s is refused before the VO."""
    ds = _euroc(shared_data, tmp_path / "ds", gyro_scale=float(np.rad2deg(1.0)))
    r = run(["vio", ds, "--out", tmp_path / "out"])
    assert_rejected(r, ["deg/s"], tmp_path, codes=(2,))
    assert "imu0" in compact(r.output)


def test_vio_imu_stamps_shared(shared_data: Path, tmp_path: Path) -> None:
    ds = _euroc(shared_data, tmp_path / "ds", one_stamp=True)
    r = run(["vio", ds, "--out", tmp_path / "out"])
    assert_rejected(r, ["imu0/data.csv"], tmp_path, codes=(2,))


# --- map2d ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "content, name",
    [
        (RANDOM, "cfg.yaml"),
        (b"loop: [1, 2\n", "cfg.yaml"),
        (b"resolution: 1.0e-9\n", "resolution"),
        (b"max_range: .inf\n", "max_range"),
        (b"loop:\n  min_score: .nan\n", "loop.min_score"),
        # a 1 km search window ran over 10 minutes on 30 scans; a min_range beyond max_range
        (b"matcher:\n  linear_window: 1000.0\n", "matcher.linear_window"),
        (b"min_range: 50.0\n", "min_range"),
    ],
)
def test_map2d_config(content: bytes, name: str, sim_room: Path, tmp_path: Path) -> None:
    cfg = tmp_path / "cfg.yaml"
    cfg.write_bytes(content)
    r = run(["map2d", sim_room, "--config", cfg, "--out", tmp_path / "out"])
    assert_rejected(r, [name], tmp_path, codes=(2,))


def test_map2d_scans_sharing_one_stamp(sim_room: Path, tmp_path: Path) -> None:
    """400 poses at one time, duration 0.0 s, exit 0: now refused, naming the scans' stamps."""
    t = np.load(sim_room / "sim.npz")["scan_t_ns"]
    one = _room_with(sim_room, tmp_path / "one", scan_t_ns=np.full_like(t, t[0]))
    r = run(["map2d", one, "--out", tmp_path / "out"])
    assert_rejected(r, [str(one)], tmp_path, codes=(2,))
    assert "29of30scanscarrythesamestamp" in compact(r.output)
    pairs = t.copy()
    pairs[1::2] = pairs[0::2][: len(pairs[1::2])]  # every second scan stamped as the one before
    two = _room_with(sim_room, tmp_path / "two", scan_t_ns=pairs)
    assert_rejected(run(["map2d", two, "--out", tmp_path / "out"]), [str(two)], tmp_path, (2,))


def test_map2d_real_log_with_one_stamp(shared_data: Path, tmp_path: Path) -> None:
    """A Radish corrected log whose 395 scans carry one time stamp."""
    log = shared_data / "carmen_radish_corrected_ple" / "belgioioso-corrected.log.gz"
    r = run(["map2d", log, "--out", tmp_path / "out"])
    assert_rejected(r, ["belgioioso"], tmp_path, codes=(2,))
    assert "395 scans" in r.output or "394 of 395" in r.output


def test_map2d_imu_in_degrees(sim_room: Path, tmp_path: Path) -> None:
    gyro = np.load(sim_room / "sim.npz")["imu_gyro"]
    deg = _room_with(sim_room, tmp_path / "deg", imu_gyro=np.rad2deg(gyro) * 10)
    r = run(["map2d", deg, "--out", tmp_path / "out"])
    assert_rejected(r, ["rad/s"], tmp_path, codes=(2,))
    assert "--no-imu" in compact(r.output)


def test_map2d_reference_of_another_log(shared_data: Path, tmp_path: Path) -> None:
    """'reference scans have 360 readings' named neither the file nor the option, after the run."""
    log = shared_data / "breezyslam_mines" / "exp1.dat"
    ref = shared_data / "carmen_radish_corrected_ple" / "intel-corrected.log.gz"
    r = run(["map2d", log, "--gt", ref, "--out", tmp_path / "out"])
    assert_rejected(r, ["--gt"], tmp_path, codes=(2,))
    assert "intel-corrected" in r.output and "exp1.dat" in r.output


# --- study ----------------------------------------------------------------------------------------
def _study(**claim: object) -> dict[str, object]:
    c: dict[str, object] = {
        "name": "c", "scenarios": [{"name": "street", "duration_s": 2.0}], "imu": ["ideal"],
        "alignment": ["none"], "estimators": [{"name": "ins"}], "compare": "imu", "eval_align": "none",
    }  # fmt: skip
    c.update(claim)
    return {"name": "t", "seeds": [0], "align": {"duration_s": 2.0}, "claims": [c]}


@pytest.mark.parametrize(
    "change, name",
    [
        ({"metric": "happiness"}, "metric"),  # the claim was "not resolved", exit 0
        ({"seeds": [2**70]}, "seeds"),  # a traceback, and cells/ left behind
        ({"seeds": [-1]}, "seeds"),
        ({"seeds": 10**9}, "seeds"),  # a count: a billion seeds
        ({"imu": ["perfect"]}, "imu"),
        ({"scenarios": [{"name": "street", "duration_s": float("inf")}]}, "duration_s"),
        (
            {"estimators": [{"name": "ins", "options": {"pose_rate_hz": float("inf")}}]},
            "pose_rate_hz",
        ),
        (  # a further configuration field: refused at load, not in every cell
            {
                "scenarios": [{"name": "square"}],
                "estimators": [{"name": "map2d", "options": {"config": {"resolution": 1e-9}}}],
            },
            "resolution",
        ),
    ],
)
def test_study_refused_before_any_cell(
    change: dict[str, object], name: str, tmp_path: Path
) -> None:
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(_study(**change)))
    r = run(["study", f, "--serial", "--out", tmp_path / "out"])
    assert_rejected(r, [name], tmp_path, codes=(2,))
    assert not (tmp_path / "out").exists()


def test_study_file_of_random_bytes(tmp_path: Path) -> None:
    f = tmp_path / "s.yaml"
    f.write_bytes(RANDOM)
    assert_rejected(run(["study", f, "--out", tmp_path / "out"]), ["s.yaml"], tmp_path, (2,))


def test_study_whose_every_cell_fails_exits_3(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from imuslam.errors import EstimatorError
    from imuslam.study import estimators

    def broken(inp: estimators.CellInput) -> estimators.Estimate:
        raise EstimatorError("scan 7: too few correspondences")

    e = estimators.REGISTRY["ins"]
    monkeypatch.setitem(estimators.REGISTRY, "ins", replace(e, run=broken))
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(_study()))
    r = run(["study", f, "--serial", "--out", tmp_path / "out"])
    assert r.exit_code == 3, r.output
    assert "Traceback" not in r.output and r.output.count("error:") == 1
    assert "everyoneofthe1cellsfailed" in compact(r.output)
    assert "scan7:toofewcorrespondences" in compact(r.output)
    assert (tmp_path / "out" / "results.csv").is_file()  # the failures are the result, kept


# --- score, align, allan --------------------------------------------------------------------------
@pytest.mark.parametrize("g", ["0", "-9.8", "nan", "98.1"])
def test_score_gravity(g: str, tmp_path: Path) -> None:
    """--g 0 was reported as calibration units that do not match the log."""
    log = write_rows(tmp_path / "imu.txt", imu_text(imu_rows()))
    r = run(["score", log, write_calibration(tmp_path / "cal.yaml"), "--g", g])
    assert_rejected(r, ["--g"], tmp_path, codes=(2,))


def test_align_noise_file_of_random_bytes(tmp_path: Path) -> None:
    log = write_rows(tmp_path / "imu.txt", imu_text(imu_rows()))
    noise = tmp_path / "imu.yaml"
    noise.write_bytes(RANDOM)
    r = run(["align", log, "--noise", noise, "--t-still", "1", "--out", tmp_path / "out"])
    assert_rejected(r, ["imu.yaml"], tmp_path, codes=(2,))


def test_align_gyro_in_degrees_declared_radians(tmp_path: Path) -> None:
    """A gimbal log (up to 1.8 rad/s) in deg/s, declared rad/s."""
    from imuslam.io.load import write_imu
    from imuslam.sim.multipose import simulate_multipose, sphere_plan_deg

    rng = np.random.default_rng(11)
    log = simulate_multipose(sphere_plan_deg(12, rng), rng).log
    p = tmp_path / "deg.txt"
    write_imu(
        ImuLog(log.t_ns, log.accel, np.rad2deg(log.gyro), "m/s^2", "rad/s", "deg"), p, "imutk"
    )
    r = run(
        ["align", p, "--accel-unit", "m/s^2", "--gyro-unit", "rad/s", "--out", tmp_path / "out"]
    )
    assert_rejected(r, ["--gyro-unit"], tmp_path, codes=(2,))
    assert "deg/s" in r.output


def test_align_still_gyro_in_degrees_declared_radians(tmp_path: Path) -> None:
    """A still log (gyro bias 1.2 deg/s) in deg/s declared rad/s: levelled with a 1.2 rad/s bias."""
    rows = imu_rows(600)
    rows[:, 4:7] = np.rad2deg(rows[:, 4:7] + [0.02, -0.01, 0.005])
    p = write_rows(tmp_path / "still.txt", imu_text(rows))
    args = ["align", p, "--accel-unit", "m/s^2", "--t-still", "2", "--method", "coarse"]
    r = run([*args, "--gyro-unit", "rad/s", "--out", tmp_path / "out"])
    assert_rejected(r, ["--gyro-unit"], tmp_path, codes=(2,))
    assert "deg/s" in r.output and "still" in r.output
    ok = run([*args, "--gyro-unit", "deg/s", "--out", tmp_path / "ok"])
    assert ok.exit_code == 0, ok.output


def test_allan_gyro_in_degrees_declared_radians(tmp_path: Path) -> None:
    """The README says a deg/s gyro declared rad/s is refused; allan analysed it (exit 0, noise 57x)."""
    rows = imu_rows(3000)
    rows[:, 4:7] = np.rad2deg(rows[:, 4:7])
    p = write_rows(tmp_path / "deg.txt", imu_text(rows))
    r = run(["allan", p, "--gyro-unit", "rad/s", "--out", tmp_path / "out"])
    assert_rejected(r, ["--gyro-unit"], tmp_path, codes=(2,))
    assert "deg/s" in r.output
    ok = run(["allan", p, "--gyro-unit", "deg/s", "--out", tmp_path / "ok"])
    assert ok.exit_code == 0, ok.output


def test_allan_real_mpu6050_in_degrees(shared_data: Path, tmp_path: Path) -> None:
    """10 min of a still MPU6050 (g, deg/s, 0.01 deg/s/sqrt(Hz)) declared rad/s, and undeclared (the
    magnitudes of a still gyro in deg/s guess rad/s): both refused."""
    from imuslam.io.matlab import read_mat_buffers

    d = (
        shared_data
        / "sunsided_mpu6050_hmc5883l"
        / "set-2"
        / "unmoved-with-x-pointing-forward-10min"
    )
    log = read_mat_buffers(d / "mpu6050_accelerometer.mat", d / "mpu6050_gyroscope.mat")
    p = tmp_path / "mpu.txt"
    np.savetxt(p, np.column_stack([log.t_ns * 1e-9, log.accel, log.gyro]), fmt="%.9g")
    for units in (["--accel-unit", "g", "--gyro-unit", "rad/s"], []):
        r = run(["allan", p, *units, "--out", tmp_path / "out"])
        assert_rejected(r, ["mpu.txt"], tmp_path, codes=(2,))
        assert "deg/s" in r.output
