"""Every command that reads a file, fed spoiled files drawn by hypothesis (derandomized): exit 2 or 3,
no traceback, one message naming the file, nothing written."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import yaml
from cli_helpers import (
    assert_rejected,
    imu_rows,
    imu_text,
    run,
    tum_rows,
    write_bag,
    write_calibration,
    write_rows,
)
from cli_strategies import bad_calibration_field, set_field, spoiled_table
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

SETTINGS = settings(
    max_examples=25,
    derandomize=True,
    phases=(Phase.explicit, Phase.generate),  # no shrinking: a failing example is printed as drawn
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
IMU = imu_text(imu_rows())
TUM = [[f"{r[0]:.4f}"] + [f"{v:.6f}" for v in r[1:]] for r in tum_rows()]

# Each command that reads an IMU log, with the options that make the rest of its input valid.
IMU_COMMANDS = {
    "calibrate": lambda log, d: ["calibrate", log, "--accel-unit", "m/s^2", "--gyro-unit", "rad/s",
                                 "--out", d / "out"],
    "correct": lambda log, d: ["correct", log, "--calib", write_calibration(d / "cal.yaml"),
                               "--out", d / "out.txt"],
    "allan": lambda log, d: ["allan", log, "--out", d / "out"],
    "align": lambda log, d: ["align", log, "--accel-unit", "m/s^2", "--gyro-unit", "rad/s",
                             "--t-still", "1", "--out", d / "out"],
}  # fmt: skip


@SETTINGS
@given(
    command=st.sampled_from(sorted(IMU_COMMANDS)),
    content=spoiled_table(IMU, value_cols=(1, 2, 3, 4, 5, 6)),
    suffix=st.sampled_from([".txt", ".csv"]),
)
def test_imu_logs(command: str, content: bytes, suffix: str) -> None:
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        log = d / f"imu{suffix}"
        log.write_bytes(content)
        r = run(IMU_COMMANDS[command](log, d))
        assert_rejected(r, [log.name], d)


@SETTINGS
@given(
    content=spoiled_table(TUM, value_cols=(1, 2, 3, 4, 5, 6, 7)),
    which=st.sampled_from(["gt", "est"]),
    align=st.sampled_from(["se3", "sim3", "yaw", "first"]),
)
def test_eval_trajectories(content: bytes, which: str, align: str) -> None:
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        good, bad = write_rows(d / "good.tum", TUM), d / "bad.tum"
        bad.write_bytes(content)
        gt, est = (bad, good) if which == "gt" else (good, bad)
        r = run(["eval", gt, est, "--align", align, "--out", d / "out"])
        assert_rejected(r, [bad.name], d)


@SETTINGS
@given(content=spoiled_table(TUM, value_cols=(1, 2, 3, 4, 5, 6, 7)))
def test_align_aiding_trajectory(content: bytes) -> None:
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        log = write_rows(d / "imu.txt", IMU)
        bad = d / "aid.tum"
        bad.write_bytes(content)
        r = run(["align", log, "--aiding", bad, "--accel-unit", "m/s^2", "--gyro-unit", "rad/s",
                 "--out", d / "out"])  # fmt: skip
        assert_rejected(r, [bad.name], d)


@SETTINGS
@given(field=bad_calibration_field())
def test_correct_calibration_fields(field: tuple[str, object]) -> None:
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        cal = write_calibration(d / "cal.yaml")
        doc = yaml.safe_load(cal.read_text())
        set_field(doc, *field)
        cal.write_text(yaml.safe_dump(doc))
        log = write_rows(d / "imu.txt", IMU)
        r = run(["correct", log, "--calib", cal, "--out", d / "out.txt"])
        assert_rejected(r, [cal.name], d)


@SETTINGS
@given(
    content=st.one_of(
        st.binary(min_size=1, max_size=200), st.sampled_from([b"\xff\xfe\x00", b"[1, 2"])
    )
)
def test_calibration_not_yaml(content: bytes) -> None:
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        cal = d / "cal.yaml"
        cal.write_bytes(content)
        r = run(["correct", write_rows(d / "imu.txt", IMU), "--calib", cal, "--out", d / "out.txt"])
        assert_rejected(r, [cal.name], d)


@SETTINGS
@given(
    key=st.sampled_from(["g", "t_init_s", "window_s", "k_values", "samples_per_interval", "bias_sign",
                         "min_intervals", "gyro_margin_s", "estimate_gyro_bias", "unknown_key", "gg"]),
    value=st.one_of(st.text(max_size=5), st.floats(-1e3, 0), st.lists(st.floats(-5, 0), max_size=2),
                    st.just({"a": 1}), st.just(-3)),
)  # fmt: skip
def test_calibrate_config(key: str, value: object) -> None:
    """A --config with a wrong value or an unknown key names the key."""
    known_ok = {  # values that happen to be valid for a field are not bad input
        "estimate_gyro_bias": lambda v: isinstance(v, bool),
        "bias_sign": lambda v: v in ("plus", "minus"),
    }
    if key in known_ok and known_ok[key](value):
        return
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        cfg = d / "cfg.yaml"
        cfg.write_text(yaml.safe_dump({key: value}))
        r = run(["calibrate", write_rows(d / "imu.txt", IMU), "--config", cfg, "--out", d / "out"])
        assert_rejected(r, [key], d)


@settings(max_examples=12, derandomize=True, deadline=None, phases=(Phase.explicit, Phase.generate))
@given(
    start=st.floats(0.3, 0.9),
    length=st.integers(8, 400),
    fill=st.sampled_from([b"\x00", b"\xff", b"\x5a"]),
    command=st.sampled_from(["allan", "calibrate"]),
)
def test_corrupted_mcap(start: float, length: int, fill: bytes, command: str) -> None:
    """An MCAP damaged in the middle (past its header and schemas) is one line naming the file.

    The format has no checksum of message data that rosbags verifies, so damage may leave readable
    messages with other values: 300 samples (3 s) are then too few for an Allan analysis or a
    calibration, which is also one line naming the bag. Damage to the structure must be reported
    as such, not as a rosbags traceback (the regression tests pin that case)."""
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        bag = write_bag(d / "imu.mcap", imu_rows(300))
        raw = bytearray(bag.read_bytes())
        k = int(start * len(raw))
        raw[k : k + length] = fill * min(length, len(raw) - k)
        bag.write_bytes(bytes(raw))
        r = run([command, bag, "--out", d / "out"])
        assert_rejected(r, [bag.name], d)


@settings(max_examples=10, derandomize=True, deadline=None, phases=(Phase.explicit, Phase.generate))
@given(
    i=st.integers(0, 299),
    col=st.integers(1, 6),
    value=st.sampled_from([np.nan, np.inf, -np.inf, 1e308]),
    command=st.sampled_from(["allan", "calibrate", "align", "correct"]),
)
def test_bag_samples(i: int, col: int, value: float, command: str) -> None:
    """A NaN, infinite or absurd sample in a bag names the bag and the message."""
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        rows = imu_rows(300)
        rows[i, col] = value
        bag = write_bag(d / "imu.mcap", rows)
        args: list[object] = [command, bag]
        args += ["--calib", write_calibration(d / "cal.yaml"), "--out", d / "out.mcap"] if (
            command == "correct") else ["--out", d / "out"]  # fmt: skip
        r = run(args)  # type: ignore[arg-type]
        assert_rejected(r, [bag.name], d)
        assert f"sample {i}" in r.output
