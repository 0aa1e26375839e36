"""No command deletes or overwrites a file it did not create: ``--out`` at the input folder, the current
folder, the parent, a user's folder and a symbolic link, every file of the user's hashed before and after.

An output that is, holds or lies inside an input is refused before any work (exit 2). An existing folder
keeps every file the command does not write; a file the command writes replaces only one that an earlier
imuslam run wrote there, and a file of the user's with the same name stops the run with nothing written.
An interrupted run (SIGINT, SIGTERM) leaves no temporary folder and ends on one line.
"""

from __future__ import annotations

import functools
import hashlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from cli_helpers import (
    assert_rejected,
    imu_rows,
    imu_text,
    run,
    tum_rows,
    write_calibration,
    write_rows,
)

from imuslam.io.results import MANIFEST

if TYPE_CHECKING:
    from imuslam.sim.drive import LidarDrive


def tree_hashes(root: Path) -> dict[str, str]:
    """Every file and link under ``root`` (hidden ones included) -> its content's SHA-1 (a link: its
    target)."""
    out: dict[str, str] = {}
    for p in sorted(root.rglob("*")):
        rel = str(p.relative_to(root))
        if p.is_symlink():
            out[rel] = "link:" + os.readlink(p)
        elif p.is_file():
            out[rel] = hashlib.sha1(p.read_bytes()).hexdigest()
    return out


def no_temporaries(root: Path) -> list[str]:
    return [str(p) for p in root.rglob("*") if ".partial-" in p.name or p.name.startswith(".lio")]


def _tum(data: Path) -> tuple[Path, Path]:
    gt = write_rows(data / "gt.tum", [[f"{v:.6f}" for v in r] for r in tum_rows(60)])
    rows = tum_rows(60, seed=1)
    rows[:, 1:4] += 0.01
    est = write_rows(data / "est.tum", [[f"{v:.6f}" for v in r] for r in rows])
    return gt, est


def _imu(data: Path) -> Path:
    return write_rows(data / "imu.txt", imu_text(imu_rows(300)))


def _clf(data: Path) -> Path:
    """A robot standing 3 m from a round wall: 40 CARMEN laser lines (fast to map)."""
    rng = np.random.default_rng(0)
    lines = []
    for k in range(40):
        r = " ".join(f"{3.0 + 0.01 * rng.standard_normal():.3f}" for _ in range(180))
        t = 100.0 + 0.1 * k
        lines.append(f"FLASER 180 {r} 0 0 0 0 0 0 {t:.3f} h {t:.3f}\n")
    f = data / "log.clf"
    f.write_text("".join(lines))
    return f


@functools.cache
def _lio_drive() -> LidarDrive:
    """0.6 s of the street (6 scans): enough for ``lio`` to write every output, plot included; the
    safety of a results folder does not depend on how long the drive is. Simulated once per module."""
    from imuslam.sim.drive import simulate_lidar_drive

    return simulate_lidar_drive("street", 0.6, seed=3)


def _lio_bag(data: Path) -> Path:
    from imuslam.sim import export

    d = _lio_drive()
    pc = [(s.t_ns, "/points", export.pointcloud_message(s)[1]) for s in d.scans]
    export.write_bag(data / "bag", [export.imu_messages(d.imu), iter(pc)])
    return data / "bag"


# command -> (inputs written into the data folder) -> arguments without --out
COMMANDS: dict[str, Callable[[Path], list[str]]] = {
    "eval": lambda d: ["eval", *map(str, _tum(d)), "--no-plots"],
    "calibrate": lambda d: ["calibrate", str(_imu(d)), "--no-plots"],
    "score": lambda d: ["score", str(_imu(d)), str(write_calibration(d / "c.yaml"))],
    "allan": lambda d: ["allan", str(_imu(d))],
    "align": lambda d: ["align", str(_imu(d))],
    "map2d": lambda d: ["map2d", str(_clf(d)), "--no-progress"],
    "lio": lambda d: ["lio", str(_lio_bag(d))],
    "study": lambda d: ["study", str(write_rows(d / "s.yaml", [["name:", "x"]]))],
}


def _user_folder(root: Path) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    (root / "notes.txt").write_text("mine\n")
    (root / "sub").mkdir(exist_ok=True)
    (root / "sub" / "scan.bin").write_bytes(bytes(range(256)))
    return root


CASES = [(c, w) for c in sorted(COMMANDS) for w in ("input folder", "current folder", "parent")]


@pytest.mark.parametrize(("command", "where"), [*CASES, ("lio", "inside the input")])
def test_out_over_the_input_is_refused_before_any_work(
    command: str, where: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--out`` at the folder that holds the input, ``.`` and ``..`` from there, or a folder inside an
    input folder (a bag folder): exit 2 naming ``--out``, every file as it was, nothing new."""
    data = _user_folder(tmp_path / "data")
    args = COMMANDS[command](data)
    out = {"input folder": str(data), "current folder": ".", "parent": "..",
           "inside the input": str(data / "bag" / "results")}[where]  # fmt: skip
    monkeypatch.chdir(data)
    before = tree_hashes(tmp_path)
    r = run([*args, "--out", out])
    assert_rejected(r, ["--out"], codes=(2,))
    assert tree_hashes(tmp_path) == before


def test_map2d_relative_current_folder_and_parent(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The issue's own cases: ``cd data && imuslam map2d ./log.clf --out .`` (and ``--out ..``)."""
    data = _user_folder(tmp_path / "data")
    _clf(data)
    monkeypatch.chdir(data)
    before = tree_hashes(tmp_path)
    for out in (".", ".."):
        assert_rejected(run(["map2d", "./log.clf", "--out", out]), ["--out"], codes=(2,))
    assert tree_hashes(tmp_path) == before


def test_vio_out_at_or_inside_the_dataset_is_refused(tmp_path: Path) -> None:
    """``vio data --out data`` and ``--out data/mav0`` (the camera folder): refused before the dataset
    is read, the folder intact."""
    data = tmp_path / "ds"
    (data / "mav0" / "cam0" / "data").mkdir(parents=True)
    (data / "mav0" / "cam0" / "data.csv").write_text("#timestamp [ns],filename\n")
    before = tree_hashes(tmp_path)
    for out in (data, data / "mav0", data / "mav0" / "cam0"):
        assert_rejected(run(["vio", str(data), "--out", str(out)]), ["--out"], codes=(2,))
    assert tree_hashes(tmp_path) == before


def test_correct_never_writes_over_a_file(tmp_path: Path) -> None:
    """``correct x.txt --out x.txt`` (the raw log) and ``--out`` another existing file: exit 2, both
    files as they were; a new name is written."""
    imu = _imu(tmp_path)
    cal = write_calibration(tmp_path / "c.yaml")
    other = tmp_path / "other.txt"
    other.write_text("user's\n")
    before = tree_hashes(tmp_path)
    for out in (imu, other, cal):
        assert_rejected(run(["correct", str(imu), "--calib", str(cal), "--out", str(out)]),
                        ["--out"], codes=(2,))  # fmt: skip
    assert tree_hashes(tmp_path) == before
    r = run(["correct", str(imu), "--calib", str(cal), "--out", str(tmp_path / "new.txt")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "new.txt").is_file()
    assert {k: v for k, v in tree_hashes(tmp_path).items() if k != "new.txt"} == before


FULL_RUNS = ["eval", "map2d", "lio"]


@pytest.mark.parametrize("kind", ["user folder", "symbolic link"])
@pytest.mark.parametrize("command", FULL_RUNS)
def test_a_users_folder_keeps_its_files(command: str, kind: str, tmp_path: Path) -> None:
    """A run into a user's folder (or a link to one) adds its files and keeps the user's; run again,
    it replaces its own files; a file of the user's named like an output stops the run, nothing written."""
    data = tmp_path / "data"
    data.mkdir()
    args = COMMANDS[command](data)
    user = _user_folder(tmp_path / "user")
    out = user
    if kind == "symbolic link":
        out = tmp_path / "link"
        out.symlink_to(user, target_is_directory=True)
    mine = tree_hashes(user)
    r = run([*args, "--out", str(out)])
    assert r.exit_code == 0, r.output
    after = tree_hashes(user)
    assert {k: after[k] for k in mine} == mine
    written = set(after) - set(mine) - {MANIFEST}
    assert written and MANIFEST in after
    assert out.is_symlink() == (kind == "symbolic link")
    assert not no_temporaries(tmp_path)
    # again into the same folder: its own files are replaced, the user's kept
    r = run([*args, "--out", str(out)])
    assert r.exit_code == 0, r.output
    again = tree_hashes(user)
    assert {k: again[k] for k in mine} == mine and set(again) == set(after)
    # a user's file with an output's name: refused after the work, nothing moved
    other = _user_folder(tmp_path / "other")
    clash = sorted(written)[0]
    (other / clash).parent.mkdir(parents=True, exist_ok=True)
    (other / clash).write_text("the user's own\n")
    before = tree_hashes(other)
    r = run([*args, "--out", str(other)])
    assert_rejected(r, [clash], codes=(2,))
    assert tree_hashes(other) == before
    assert not no_temporaries(tmp_path)


def test_two_runs_into_one_folder_lose_nothing(tmp_path: Path) -> None:
    """Two runs of different commands into one user folder: both sets of results and the user's files."""
    data = tmp_path / "data"
    data.mkdir()
    user = _user_folder(tmp_path / "user")
    mine = tree_hashes(user)
    assert run([*COMMANDS["eval"](data), "--out", str(user)]).exit_code == 0
    first = tree_hashes(user)
    r = run([*COMMANDS["map2d"](data), "--out", str(user)])
    assert r.exit_code == 0, r.output
    final = tree_hashes(user)
    assert {k: final[k] for k in mine} == mine
    assert "metrics.json" in first and "map.pgm" in final and "trajectory.tum" in final


def test_a_dangling_link_as_out_is_refused(tmp_path: Path) -> None:
    data = tmp_path / "data"
    data.mkdir()
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "nowhere")
    assert_rejected(run([*COMMANDS["eval"](data), "--out", str(link)]), ["--out"], codes=(2,))
    assert link.is_symlink() and not (tmp_path / "nowhere").exists()


def test_the_old_results_folder_replacement_is_gone(tmp_path: Path) -> None:
    """``atomic_path`` never removes an existing folder: writing a folder (a ROS 2 bag) over one fails
    and leaves it as it was."""
    from imuslam.io.atomic import atomic_path

    user = _user_folder(tmp_path / "bag")
    before = tree_hashes(tmp_path)
    with pytest.raises(FileExistsError), atomic_path(user) as tmp:
        tmp.mkdir()
        (tmp / "metadata.yaml").write_text("x")
    assert tree_hashes(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]


def test_an_interrupt_inside_a_kernel_is_an_interrupt() -> None:
    """A signal that arrives inside a compiled kernel surfaces as a SystemError whose context is the
    interrupt: the command line reports it as the interrupt (exit 130 / 143), a study re-raises it."""
    from imuslam.cli.common import Interrupted, _interrupt
    from imuslam.errors import raise_if_interrupted

    def kernel_error(intr: BaseException) -> SystemError:
        try:
            try:
                raise intr
            except BaseException:
                raise SystemError("<function> returned a result with an exception set")  # noqa: B904
        except SystemError as e:
            return e

    e = kernel_error(Interrupted(signal.SIGTERM))
    got = _interrupt(e)
    assert got is not None and got.signum == signal.SIGTERM
    with pytest.raises(KeyboardInterrupt):
        raise_if_interrupted(kernel_error(KeyboardInterrupt()))
    assert _interrupt(ValueError("not an interrupt")) is None
    raise_if_interrupted(ValueError("not an interrupt"))  # returns


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_the_run_and_leaves_nothing(sig: int, tmp_path: Path) -> None:
    """``imuslam simulate street`` (tens of seconds of work) signalled 1 s after its output folder's
    temporary sibling appears (inside the simulation's work, which writes into it), or after 8 s: exit
    128 + signal, one line, no traceback, nothing in the folder."""
    out = tmp_path / "sim"
    exe = Path(sys.executable).with_name("imuslam")
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [str(exe), "simulate", "street", "--duration", "120", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    deadline = time.monotonic() + 8.0
    while time.monotonic() < deadline and proc.poll() is None:
        if no_temporaries(tmp_path):  # the work has begun: signal 1 s into it
            deadline = min(deadline, time.monotonic() + 1.0)
        time.sleep(0.1)
    assert no_temporaries(tmp_path), "no temporary folder: the run had not begun its work"
    assert proc.poll() is None, "the simulation ended before the signal"
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 128 + sig, (proc.returncode, stderr[-2000:])
    assert "Traceback" not in stderr + stdout
    assert stderr.count("error:") == 1 and "interrupted" in stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["map2d", "lio"])
def test_full_disk_names_out_and_leaves_nothing(command: str, tmp_path: Path) -> None:
    """The disk fills while the plot is written: exit 2 naming --out and the cause, a new folder not
    created, an existing one as it was."""
    import errno
    from unittest import mock

    def full(path: object, data: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    data = tmp_path / "data"
    data.mkdir()
    args = COMMANDS[command](data)
    user = _user_folder(tmp_path / "user")
    before = tree_hashes(user)
    with mock.patch("imuslam.io.figures.write_atomic", full):
        for out in (tmp_path / "new", user):
            r = run([*args, "--out", str(out)])
            assert_rejected(r, ["--out"], codes=(2,))
            assert "No space left" in r.output
    assert not (tmp_path / "new").exists()
    assert tree_hashes(user) == before
    assert not no_temporaries(tmp_path)


# every command (a cheap input each: some runs succeed, some are refused as bad input, none may touch
# a file of the user's); the simulator's commands have no input file to overlap
EVERY = {
    **COMMANDS,
    "simulate": lambda d: ["simulate", "room", "--duration", "3"],
    "vio": lambda d: ["vio", "sim", "--sim-duration", "1", "--sim-rate", "5"],
    "correct": lambda d: [
        "correct",
        str(_imu(d)),
        "--calib",
        str(write_calibration(d / "c.yaml")),
    ],  # fmt: skip
}


@pytest.mark.parametrize("kind", ["user folder", "symbolic link"])
@pytest.mark.parametrize("command", sorted(EVERY))
def test_no_command_touches_a_users_files(command: str, kind: str, tmp_path: Path) -> None:
    """Whatever the run's outcome (results, or a one-line refusal), every file of the user's folder
    (reached directly or through a link) is as it was, and nothing temporary is left."""
    data = tmp_path / "data"
    data.mkdir()
    args = EVERY[command](data)
    user = _user_folder(tmp_path / "user")
    (user / "config.yaml").write_text("the user's own config\n")  # a name most commands write
    (user / "metrics.json").write_text("{}\n")
    out = user
    if kind == "symbolic link":
        out = tmp_path / "link"
        out.symlink_to(user, target_is_directory=True)
    before = tree_hashes(user)
    r = run([*args, "--out", str(out)])
    assert r.exit_code in (0, 2, 3), r.output
    assert "Traceback" not in r.output
    after = tree_hashes(user)
    assert {k: after.get(k) for k in before} == before
    assert not no_temporaries(tmp_path)
