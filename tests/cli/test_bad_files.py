"""Every command that reads a file, fed spoiled files drawn by hypothesis (derandomized): exit 2 or 3,
no traceback, one message naming the file, nothing written."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
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
from cli_strategies import _not_utf8, bad_calibration_field, set_field, spoiled_table
from click.testing import Result
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
    "score": lambda log, d: ["score", log, write_calibration(d / "cal.yaml"), "--accel-unit", "m/s^2",
                             "--gyro-unit", "rad/s", "--t-init", "0.5", "--out", d / "out"],
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
                    st.just({"a": 1}), st.just(-3), st.sampled_from([np.inf, -np.inf, np.nan])),
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


# --- YAML files of the estimators, the study and the noise / calibration files --------------------
#: Bytes no YAML reader may take as a mapping: not text, a syntax error, another top-level type.
damaged_yaml = st.one_of(
    st.binary(min_size=1, max_size=200).filter(lambda b: _not_utf8(b)),
    st.sampled_from([b"a: [1, 2\n", b"{a: 1\n", b"key: 'open\n", b"a: b: c\n", b"\tkey: 1\n",
                     b"just text\n", b"- 1\n- 2\n", b"42\n", b"a: 1\x00\n", b"[" * 5000]),
)  # fmt: skip


def _yaml_user(command: str, f: Path, d: Path) -> list[object]:
    """The command line of ``command`` reading ``f`` as its YAML (other inputs valid, or never reached:
    a command reads its YAML before its data)."""
    imu = write_rows(d / "imu.txt", IMU)
    return {
        "lio": ["lio", d / "scans.bag", "--config", f],
        "vio": ["vio", "sim", "--config", f],
        "vio-camchain": ["vio", d / "euroc", "--camchain", f],
        "map2d": ["map2d", d / "scans.clf", "--config", f],
        "study": ["study", f, "--serial"],
        "align-noise": ["align", imu, "--noise", f, "--accel-unit", "m/s^2", "--gyro-unit", "rad/s",
                        "--t-still", "1"],
        "score": ["score", imu, f, "--accel-unit", "m/s^2", "--gyro-unit", "rad/s"],
        "correct": ["correct", imu, "--calib", f],
    }[command] + ["--out", d / ("out.txt" if command == "correct" else "out")]  # fmt: skip


YAML_COMMANDS = ("lio", "vio", "vio-camchain", "map2d", "study", "align-noise", "score", "correct")


@SETTINGS
@given(command=st.sampled_from(YAML_COMMANDS), content=damaged_yaml)
def test_damaged_yaml(command: str, content: bytes) -> None:
    """Every YAML a command reads goes through one reader: one line naming the file, exit 2."""
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        f = d / "input.yaml"
        f.write_bytes(content)
        r = run(_yaml_user(command, f, d))  # type: ignore[arg-type]
        assert_rejected(r, ["input.yaml"], d, codes=(2,))


NAN, INF = float("nan"), float("inf")
GENERIC = [NAN, INF, -INF, "abc"]  # and a list, where a number is expected
#: command -> {dotted field: values it must refuse beside GENERIC}; every value is invalid there.
FIELDS: dict[str, dict[str, list[object]]] = {
    "lio": {"filter.lidar_std": [0, -1], "filter.g": [0, 98.1, 1.0], "map.voxel": [1e-9, 0, 1e3],
            "frontend.scan_voxel": [1e-9, -0.5], "extrinsic.time_offset_s": [1.7e9, -5],
            "filter.max_iterations": [0, 10**6, 1.5], "align_seconds": [0, 1e7], "map.radius": [0, 1e9],
            "map.max_per_voxel": [0, 10**5]},
    "vio": {"noise.gyro": [0, -1], "nhc_rate_hz": [0, 1e6], "vo.max_features": [0, 5, 10**7], "vo.search_coarse_px": [0, 10**5], "vo.blur_sigma": [-1, 1e6],
            "g": [0, 98.1], "outlier_fraction": [1.0, -0.1], "outlier_seed": [-1, 2**40]},
    "map2d": {"resolution": [1e-9, 0, 5], "loop.min_score": [0, 1, 2], "max_range": [0, -3],
              "matcher.max_iterations": [0, -2], "matcher.linear_window": [1e3, -1]},
    "study": {"claims.0.scenarios.0.duration_s": [0, -1, 1e9], "align.fix_rate_hz": [0, -10],
              "seeds": [[-1], [2**40], ["x"], 10**9], "drift.age_h": [-1, 1e9], "align.duration_s": [0, 1e9], "claims.0.metric": ["happiness"]},
}  # fmt: skip
STUDY = {"name": "t", "seeds": [0], "claims": [{
    "name": "c", "scenarios": [{"name": "street", "duration_s": 2.0}], "estimators": [{"name": "ins"}],
    "compare": "imu"}]}  # fmt: skip


def _put(doc: dict[str, object], path: str, value: object) -> None:
    keys = path.split(".")
    node: object = doc
    for k in keys[:-1]:
        node = node[int(k)] if k.isdigit() else node.setdefault(k, {})  # type: ignore[index, union-attr]
    node[keys[-1]] = value  # type: ignore[index]


@st.composite
def bad_field(draw: st.DrawFn) -> tuple[str, str, object]:
    command = draw(st.sampled_from(sorted(FIELDS)))
    field = draw(st.sampled_from(sorted(FIELDS[command])))
    generic = GENERIC if field == "seeds" else [*GENERIC, [1, 2]]
    return command, field, draw(st.sampled_from(generic + FIELDS[command][field]))


@SETTINGS
@given(case=bad_field())
def test_config_field_values(case: tuple[str, str, object]) -> None:
    """A value that is NaN, infinite, of another type or in another unit is refused before any work,
    naming the field (.inf and 1e-9 passed and failed later, exit 3, naming nothing)."""
    import copy

    command, field, value = case
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        doc: dict[str, object] = copy.deepcopy(STUDY) if command == "study" else {}
        _put(doc, field, value)
        f = d / "input.yaml"
        f.write_text(yaml.safe_dump(doc))
        r = run(_yaml_user(command, f, d))  # type: ignore[arg-type]
        assert_rejected(r, [field.rsplit(".", 1)[-1]], d, codes=(2,))


# --- damaged data of the estimators: a bag (lio), a CARMEN log and a simulation (map2d) ----------
def carmen_text(n: int = 40) -> str:
    """A CARMEN log of ``n`` FLASER scans (180 beams over 180 deg, 10 Hz) of a robot driving 5 cm a
    scan along x in a 6 m x 4 m room; laser pose = odometry."""
    out = []
    ang = -np.pi / 2 + np.pi / 180 * np.arange(180)
    for i in range(n):
        x = -1.0 + 0.05 * i
        c, s = np.cos(ang), np.sin(ang)
        with np.errstate(divide="ignore"):
            tx = np.where(c > 0, (3.0 - x) / c, np.where(c < 0, (-3.0 - x) / c, np.inf))
            ty = np.where(s > 0, 2.0 / s, np.where(s < 0, -2.0 / s, np.inf))
        r = np.minimum(tx, ty)
        t = 1000.0 + 0.1 * i
        out.append(f"FLASER 180 {' '.join(f'{v:.3f}' for v in r)} {x:.3f} 0 0 {x:.3f} 0 0 "
                   f"{t:.3f} host {t:.3f}")  # fmt: skip
    return "\n".join(out) + "\n"


Recipe = tuple[str, int, int, bytes]


@st.composite
def damage(draw: st.DrawFn, n: int, text: bool) -> Recipe:
    """How to damage ``n`` bytes (kept small, so a failing example prints readably): cut short, a
    span overwritten (random bytes or zeros), bytes inserted or deleted; for text, also a token of a
    line replaced (a word, NaN, an absurd value) or two lines swapped."""
    kinds = ["truncate", "overwrite", "zeros", "insert", "delete"] + (
        ["token", "swap"] if text else []
    )
    kind = draw(st.sampled_from(kinds))
    k = draw(st.integers(n // 20, n - 2))
    span = draw(st.integers(1, max(1, min(400, n - k - 1))))
    if kind == "overwrite":
        return kind, k, span, draw(st.binary(min_size=span, max_size=span))
    if kind == "insert":
        return kind, k, span, draw(st.binary(min_size=1, max_size=64))
    if kind == "token":
        word = draw(
            st.sampled_from(["nan", "inf", "-1e308", "1e20", "abc", "", "99999999999999999999"])
        )
        return kind, k, span, word.encode()
    return kind, k, span, b""


def apply_damage(raw: bytes, recipe: Recipe) -> bytes:
    kind, k, span, payload = recipe
    if kind == "truncate":
        return raw[:k]
    if kind in ("overwrite", "zeros"):
        return raw[:k] + (payload or b"\x00" * span) + raw[k + span :]
    if kind == "insert":
        return raw[:k] + payload + raw[k:]
    if kind == "delete":
        return raw[:k] + raw[k + span :]
    lines = raw.decode().splitlines()
    i = 1 + k % (len(lines) - 1)
    if kind == "swap":
        lines[i - 1], lines[i] = lines[i], lines[i - 1]
    else:
        tok = lines[i].split()
        tok[1 + span % (len(tok) - 1)] = payload.decode()
        lines[i] = " ".join(tok)
    return ("\n".join(lines) + "\n").encode()


def assert_clean(r: Result, names: list[str]) -> None:
    """The law for damaged data: exit 0, 2 or 3, no traceback; a failure is one line naming the file."""
    assert r.exit_code in (0, 2, 3), f"exit {r.exit_code}: {r.output!r} {r.exception!r}"
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert "Traceback" not in r.output
    if r.exit_code:
        assert r.output.count("error:") == 1, r.output
        assert any(compact(n) in compact(r.output) for n in names), r.output


_BASE: dict[str, bytes] = {}


def _base(kind: str) -> bytes:
    """The valid input of each kind, made once."""
    if kind not in _BASE:
        with tempfile.TemporaryDirectory() as td:
            d = Path(td)
            if kind == "bag":
                from imuslam.sim import export
                from imuslam.sim.drive import simulate_lidar_drive

                dr = simulate_lidar_drive("street", 1.0, seed=5)
                pc = [(s.t_ns, "/points", export.pointcloud_message(s)[1]) for s in dr.scans]
                export.write_bag(d / "bag", [export.imu_messages(dr.imu), iter(pc)])
                _BASE[kind] = next((d / "bag").glob("*.mcap")).read_bytes()
            elif kind == "sim":
                assert (
                    run(["simulate", "room", "--duration", "2", "--out", d / "room"]).exit_code == 0
                )
                _BASE[kind] = (d / "room" / "sim.npz").read_bytes()
            else:
                _BASE[kind] = carmen_text().encode()
    return _BASE[kind]


@st.composite
def damaged_input(draw: st.DrawFn) -> tuple[str, Recipe]:
    kind = draw(st.sampled_from(["bag", "sim", "carmen"]))
    return kind, draw(damage(len(_base(kind)), text=kind == "carmen"))


@settings(max_examples=15, derandomize=True, deadline=None, phases=(Phase.explicit, Phase.generate),
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])  # fmt: skip
@given(case=damaged_input())
def test_damaged_estimator_data(case: tuple[str, Recipe]) -> None:
    """lio on a damaged MCAP, map2d on a damaged simulation or CARMEN log: it runs (the damage was
    in data the reader may drop and count) or stops with one line naming the file."""
    kind, recipe = case
    content = apply_damage(_base(kind), recipe)
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        if kind == "bag":
            (d / "bag").mkdir()
            f = d / "bag" / "bag.mcap"
            f.write_bytes(content)
            args = ["lio", f, "--max-scans", "3", "--mode", "direct"]
        elif kind == "sim":
            (d / "room").mkdir()
            f = d / "room" / "sim.npz"
            f.write_bytes(content)
            args = ["map2d", d / "room", "--no-progress"]
        else:
            f = d / "log.clf"
            f.write_bytes(content)
            args = ["map2d", f, "--no-progress"]
        r = run([*args, "--out", d / "out"])  # type: ignore[list-item]
        assert_clean(r, [f.name, f.parent.name])
