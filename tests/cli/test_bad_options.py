"""Every option of every command, fed values drawn by hypothesis (derandomized) outside what it
accepts, and every kind of unusable --out: exit 2 before any work, one message naming the option."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from unittest import mock

from cli_helpers import assert_rejected, imu_rows, imu_text, run, tum_rows, write_rows
from cli_strategies import bad_choice, bad_float, bad_int
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from imuslam.io import results

SETTINGS = settings(
    max_examples=100,
    derandomize=True,
    phases=(Phase.explicit, Phase.generate),  # no shrinking: a failing example is printed as drawn
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
FORMATS = ("auto", "imutk", "euroc", "csv", "bag", "matlab")
TRAJ = ("tum", "kitti", "euroc", "bag")


def positive(hi: float | None = None) -> st.SearchStrategy[str]:
    """Values a positive (<= hi) option refuses: zero, negatives, beyond hi, non-finite, words."""
    return st.one_of(st.just("0"), st.just("-0.0"), bad_float(0.0, hi))


#: Seeds no generator takes: negative, beyond 32 bits (numpy's legacy RandomState), not integers.
bad_seed = st.one_of(st.integers(-(10**12), -1).map(str), st.integers(2**32, 2**80).map(str),
                     st.sampled_from(["1.5", "x", "nan"]))  # fmt: skip

# command -> (positional arguments, {option: strategy of values it must refuse})
OPTIONS: dict[str, tuple[list[str], dict[str, st.SearchStrategy[str]]]] = {
    "calibrate": (["imu.txt"], {
        "--g": bad_float(9.7, 9.9), "--t-init": positive(),
        "--bias-sign": bad_choice(("plus", "minus")), "--accel-unit": bad_choice(("m/s^2", "g", "counts")),
        "--gyro-unit": bad_choice(("rad/s", "deg/s", "counts")), "--format": bad_choice(FORMATS),
    }),
    "correct": (["imu.txt", "--calib", "cal.yaml", "--out", "o.txt"], {
        "--format": bad_choice(FORMATS), "--accel-unit": bad_choice(("m/s^2", "g", "counts")),
        "--gyro-unit": bad_choice(("rad/s", "deg/s", "counts")),
    }),
    "allan": (["imu.txt"], {
        "--format": bad_choice(FORMATS), "--accel-unit": bad_choice(("m/s^2", "g", "counts")),
        "--gyro-unit": bad_choice(("rad/s", "deg/s", "counts")),
    }),
    "align": (["imu.txt"], {
        "--method": bad_choice(("coarse", "kf", "stkf", "rwnn")), "--aiding-format": bad_choice(("auto", *TRAJ)),
        "--aiding-std": positive(), "--init": bad_choice(("auto", "coarse", "aiding")), "--g": bad_float(9.7, 9.9),
        "--t-still": positive(), "--lat-deg": bad_float(-90, 90), "--heading-deg": bad_float(-360, 360),
        "--format": bad_choice(FORMATS), "--accel-unit": bad_choice(("m/s^2", "g")),
        "--gyro-unit": bad_choice(("rad/s", "deg/s")),
    }),
    "eval": (["gt.tum", "est.tum"], {
        "--format": bad_choice(("auto", *TRAJ)), "--est-format": bad_choice(("auto", *TRAJ)),
        "--align": bad_choice(("se3", "sim3", "yaw", "first", "none")), "--rpe-delta": positive(),
        "--rpe-unit": bad_choice(("frames", "m")), "--max-diff": positive(),
    }),
    "simulate": (["room"], {"--duration": positive(3600.0), "--seed": bad_int(0)}),
    "online": (["--sim"], {
        "--duration-h": positive(168.0), "--drift-accel": bad_float(-1, 1), "--drift-gyro": bad_float(-0.1, 0.1),
        "--poses": bad_int(12, 200), "--t-init": positive(600.0), "--gimbal": bad_choice(("pca9685",)),
        "--rate": positive(1000.0), "--seed": bad_int(0),
    }),
    "demo": ([], {"--poses": bad_int(12, 200), "--seed": bad_int(0)}),
    "lio": (["scans.bag"], {
        "--state": bad_choice(("reduced", "full")), "--mode": bad_choice(("features", "direct")),
        "--align": bad_choice(("none", "kf", "stkf", "rwnn")), "--max-scans": bad_int(2),
    }),
    "vio": (["sim"], {
        "--sim-duration": bad_float(1.0, 3600.0), "--sim-rate": bad_float(1.0, 100.0), "--seed": bad_seed,
        "--g": bad_float(9.7, 9.9), "--outliers": bad_float(0.0, 1.0), "--detector": bad_choice(("sift", "orb")),
        "--align": bad_choice(("se3", "sim3", "yaw", "first")), "--gt-format": bad_choice(("auto", "tum", "euroc")),
    }),
    "map2d": (["scans.clf"], {"--format": bad_choice(("auto", "carmen", "breezyslam", "bag", "sim"))}),
    "study": (["study.yaml"], {"--workers": bad_int(1)}),
    "score": (["imu.txt", "cal.yaml"], {
        "--g": bad_float(9.7, 9.9), "--t-init": positive(), "--format": bad_choice(FORMATS),
        "--accel-unit": bad_choice(("m/s^2", "g", "counts")), "--gyro-unit": bad_choice(("rad/s", "deg/s", "counts")),
    }),
}  # fmt: skip


@st.composite
def bad_option(draw: st.DrawFn) -> tuple[str, list[str], str, str]:
    command = draw(st.sampled_from(sorted(OPTIONS)))
    args, opts = OPTIONS[command]
    opt = draw(st.sampled_from(sorted(opts)))
    return command, args, opt, draw(opts[opt])


@SETTINGS
@given(case=bad_option())
def test_option_values(case: tuple[str, list[str], str, str]) -> None:
    command, args, opt, value = case
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        write_rows(d / "imu.txt", imu_text(imu_rows()))
        tum = [[f"{v:.6f}" for v in r] for r in tum_rows()]
        write_rows(d / "gt.tum", tum), write_rows(d / "est.tum", tum)
        full = [command, *[str(d / a) if "." in a and a != "--sim" else a for a in args],
                f"{opt}={value}", "--out", str(d / "out")]  # fmt: skip
        if command == "correct":  # its --out is a file
            full[-1] = str(d / "out.txt")
        r = run(full)
        assert_rejected(r, [opt], d)


OUT_COMMANDS = {
    "calibrate": ["imu.txt"],
    "allan": ["imu.txt"],
    "align": ["imu.txt"],
    "eval": ["gt.tum", "est.tum"],
    "simulate": ["room", "--duration", "1"],
    "online": ["--sim", "--duration-h", "0.01"],
    "demo": [],
}


@settings(max_examples=30, derandomize=True, deadline=None, phases=(Phase.explicit, Phase.generate))
@given(
    command=st.sampled_from(sorted(OUT_COMMANDS)),
    kind=st.sampled_from(["existing file", "under a file", "not writable"]),
)
def test_out_folder(command: str, kind: str) -> None:
    """A results folder that cannot be: refused before any work (the inputs are never read)."""
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        (d / "afile").write_text("x")
        out = {"existing file": d / "afile", "under a file": d / "afile" / "sub" / "out",
               "not writable": d / "ro" / "out"}[kind]  # fmt: skip
        (d / "ro").mkdir()
        os.chmod(d / "ro", 0o500)
        real_access = os.access

        def access(path: object, mode: int) -> bool:  # root writes anywhere: refuse as for a user
            if Path(str(path)) == d / "ro" and mode & os.W_OK:
                return False
            return real_access(path, mode)  # type: ignore[arg-type]

        ins = [str(d / a) if a.endswith((".txt", ".tum")) else a for a in OUT_COMMANDS[command]]
        try:
            with mock.patch.object(results.os, "access", access):
                r = run([command, *ins, "--out", str(out)])
        finally:
            os.chmod(d / "ro", 0o700)
        assert_rejected(r, ["--out"], None)
        assert (d / "afile").read_text() == "x" and list((d / "ro").iterdir()) == []


@settings(max_examples=6, derandomize=True, deadline=None, phases=(Phase.explicit, Phase.generate))
@given(kind=st.sampled_from(["existing folder", "under a file"]))
def test_correct_out_file(kind: str) -> None:
    with tempfile.TemporaryDirectory() as td:
        d = Path(td)
        (d / "afile").write_text("x")
        (d / "afolder").mkdir()
        out = d / "afolder" if kind == "existing folder" else d / "afile" / "o.txt"
        log = write_rows(d / "imu.txt", imu_text(imu_rows()))
        r = run(["correct", log, "--calib", d / "cal.yaml", "--out", out])
        assert_rejected(r, ["--out"], None)
