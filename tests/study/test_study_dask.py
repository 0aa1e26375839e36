"""A study sent to a real Dask cluster (``dask scheduler`` and ``dask worker`` as separate processes on
localhost) gives the same numbers as the same study run serially in this process."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from imuslam.cli import app
from imuslam.study.config import parse_study
from imuslam.study.runner import run_study

SRC = Path(__file__).resolve().parents[2] / "src"


def _dask_cli() -> str:
    exe = Path(sys.executable).parent / "dask"
    found = str(exe) if exe.exists() else shutil.which("dask")
    assert found, (
        "the dask CLI (dask[distributed]) is a dependency of imuslam and must be installed"
    )
    return found


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[str]:
    """A scheduler and one single-threaded worker, each its own process; yields the address."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    addr = f"tcp://127.0.0.1:{port}"
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")]),
    }
    dask = _dask_cli()
    logs = [open(tmp_path / n, "w") for n in ("scheduler.log", "worker.log")]  # noqa: SIM115
    procs = [
        subprocess.Popen(
            [dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
            env=env,
            stdout=logs[0],
            stderr=subprocess.STDOUT,
        ),  # fmt: skip
    ]
    try:
        procs.append(
            subprocess.Popen(
                [
                    dask,
                    "worker",
                    addr,
                    "--nworkers",
                    "1",
                    "--nthreads",
                    "1",
                    "--no-dashboard",
                    "--local-directory",
                    str(tmp_path / "w"),
                ],
                env=env,
                stdout=logs[1],
                stderr=subprocess.STDOUT,
            )  # fmt: skip
        )
        from distributed import Client

        with Client(addr, timeout="30s") as c:
            c.wait_for_workers(1, timeout=60)
        yield addr
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        for f in logs:
            f.close()


def test_scheduler_equals_serial(cluster: str, tmp_path: Path) -> None:
    study = {
        "name": "dask",
        "seeds": [0, 1],
        "align": {"duration_s": 20.0},
        "claims": [
            {"name": "align", "scenarios": [{"name": "street", "duration_s": 10.0}], "imu": ["online"],
             "alignment": ["none", "kf", "rwnn"], "estimators": [{"name": "ins"}], "compare": "alignment",
             "expect": ["rwnn", "kf", "none"], "eval_align": "none", "practical_bound": 0.05,
             "reason": "5 cm", "max_seeds": 2},
            {"name": "calib", "scenarios": [{"name": "room", "duration_s": 10.0}],
             "imu": ["raw", "online"], "alignment": ["kf"], "estimators": [{"name": "ins"}],
             "compare": "imu", "practical_bound": 0.05, "reason": "5 cm", "max_seeds": 2},
        ],
    }  # fmt: skip
    import yaml

    f = tmp_path / "study.yaml"
    f.write_text(yaml.safe_dump(study))
    r = CliRunner().invoke(
        app, ["study", str(f), "--out", str(tmp_path / "dask"), "--scheduler", cluster]
    )
    assert r.exit_code == 0, r.output
    assert f"dask {cluster} (1 workers)" in r.output
    remote = pd.read_parquet(tmp_path / "dask" / "results.parquet")
    serial = run_study(parse_study(study), tmp_path / "serial", serial=True, progress=False).table
    assert len(remote) == 10 and (remote["status"] == "ok").all(), remote[["error"]]
    _same_numbers(remote, serial)


def _same_numbers(a: pd.DataFrame, b: pd.DataFrame) -> None:
    """Every cell is seeded from its content, wherever it runs: factors, keys and statuses equal, metrics
    equal to 1e-6 relative (a Dask worker runs BLAS single-threaded, this process does not: the last
    bits of a matrix product differ, and 10 s of free INS turn them into 2e-9 relative; before the
    shared inertial core landed they were identical)."""
    cols = [c for c in b.columns if not c.startswith("t_")]
    num = [c for c in cols if b[c].dtype.kind == "f"]
    pd.testing.assert_frame_equal(
        a[[c for c in cols if c not in num]], b[[c for c in cols if c not in num]]
    )
    pd.testing.assert_frame_equal(a[num], b[num], check_exact=False, rtol=1e-6, atol=0.0)


def test_local_cluster_equals_serial(tmp_path: Path) -> None:
    """The default in-process LocalCluster (one worker process) gives the serial numbers too, over two
    looks on the same cluster (one seed first: too few to decide, so the second seed is added)."""
    study = parse_study({"seeds": [0], "align": {"duration_s": 20.0}, "claims": [
        {"name": "a", "scenarios": [{"name": "street", "duration_s": 10.0}], "imu": ["online"],
         "alignment": ["stkf", "rwnn"], "estimators": [{"name": "ins"}], "compare": "alignment",
         "practical_bound": 0.05, "reason": "5 cm", "max_seeds": 2}]})  # fmt: skip
    local = run_study(study, tmp_path / "local", workers=1, progress=False)
    assert local.backend == "dask LocalCluster (1 workers)"
    serial = run_study(study, tmp_path / "serial", serial=True, progress=False).table
    assert (local.table["status"] == "ok").all(), local.table[["error"]]
    assert sorted(local.table.seed.unique()) == [0, 1]
    _same_numbers(local.table, serial)


def _worker_threads() -> dict[str, str | int | None]:
    import numba

    return {
        "numba": numba.config.NUMBA_NUM_THREADS,  # type: ignore[attr-defined]
        **{k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")},
    }


def test_local_cluster_workers_run_one_thread_each(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each LocalCluster worker is one process with numba, OpenMP and BLAS held to one thread (set
    before the worker imported numba), and this process keeps its own environment."""
    from imuslam.study.runner import dask_client

    monkeypatch.delenv("NUMBA_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    with dask_client(None, 2) as client:
        info = client.scheduler_info()["workers"]
        assert len(info) == 2 and all(w["nthreads"] == 1 for w in info.values())
        assert len(set(client.run(os.getpid).values())) == 2  # two processes
        for got in client.run(_worker_threads).values():
            assert got == {"numba": 1, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    assert os.environ["OMP_NUM_THREADS"] == "7" and "NUMBA_NUM_THREADS" not in os.environ
