"""Error types by meaning: a library call that breaks its own contract (a wrong shape, an unknown name
that the command line takes as a choice, an argument no command can produce) raises a plain ValueError,
which the command line does not turn into an exit-2 message; bad data stays an InputError."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import numpy as np
import pytest

from imuslam.errors import InputError
from imuslam.eval.metrics import rpe_pairs
from imuslam.eval.relations import relation_error
from imuslam.imu.allan import allan, overlapped_adev
from imuslam.imu.model import ImuCalibration, TriadModel
from imuslam.imu.online import OnlineCalibrator
from imuslam.imu.score import score_calibrations
from imuslam.ins.align import Aiding, run_alignment
from imuslam.ins.kf import KfNoise
from imuslam.ins.measurement import chi2_threshold
from imuslam.ins.preintegration import PreintegratedImu
from imuslam.ins.rwnn import run_rwnn
from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.lidar import Scan3d
from imuslam.interfaces.nav import NavState
from imuslam.interfaces.trajectory import Trajectory
from imuslam.lio.config import LioConfig
from imuslam.lio.estimator import LioEstimator
from imuslam.lio.pipeline import clean_scan
from imuslam.sim.scenario import run_scenario
from imuslam.study.config import StudyConfig
from imuslam.study.estimators import get_estimator
from imuslam.study.logstudy import _run_vio
from imuslam.study.runner import plan
from imuslam.study.scenes import scene

T = np.arange(10) * 0.1
Z = np.zeros((10, 3))


def _still_log() -> ImuLog:
    t_ns = np.arange(200, dtype=np.int64) * 10_000_000
    accel = np.tile([0.0, 0.0, 9.80665], (200, 1))
    return ImuLog(t_ns, accel, np.zeros((200, 3)), source="still.csv")


def _aiding() -> Aiding:
    return Aiding(T + 0.1, "zupt", Z, 0.01)


def _start() -> NavState:
    return NavState(np.zeros(3), np.zeros(3), np.eye(3))


def _line(n: int = 10) -> Trajectory:
    p = np.c_[np.arange(n, dtype=float), np.zeros(n), np.zeros(n)]
    return Trajectory(np.arange(n, dtype=np.int64) * 10**8, p, np.tile(np.eye(3), (n, 1, 1)))


def _flat_scan() -> Scan3d:
    """Points (5, 2): no reader makes them (every one gives x, y, z)."""
    n = 5
    return Scan3d(0, np.zeros((n, 2), np.float32), np.zeros(n, np.float32),
                  np.zeros(n, np.uint16), np.zeros(n, np.float32))  # fmt: skip


def _g_sensitive() -> ImuCalibration:
    return ImuCalibration(TriadModel(), TriadModel(), gyro_g_sensitivity=np.eye(3) * 1e-4)


MISUSE: dict[str, tuple[Callable[[Path], object], str]] = {
    "aiding kind": (lambda _: Aiding(T, "heading", Z, 0.01), "aiding kind 'heading'"),
    "aiding shape": (lambda _: Aiding(T, "zupt", np.zeros((10, 2)), 0.01), r"values \(M, 3\)"),
    "alignment method": (
        lambda _: run_alignment(_still_log(), _aiding(), _start(), "ekf"),  # type: ignore[arg-type]
        "alignment method 'ekf'",
    ),
    "P0_diag length": (
        lambda _: run_alignment(_still_log(), _aiding(), _start(), "kf", P0_diag=np.ones(9)),
        "P0_diag has 9 entries",
    ),
    "rwnn aiding kind": (
        lambda _: run_rwnn(T, Z, Z, T, Z, "heading", np.zeros(3), np.zeros(3), np.eye(3)),
        "aiding kind",
    ),
    "rwnn aiding std": (
        lambda _: run_rwnn(T, Z, Z, T, Z, "zupt", np.zeros(3), np.zeros(3), np.eye(3), aid_std=0.0),
        "1-sigma",
    ),
    "rwnn accel noise": (
        lambda _: run_rwnn(
            T, Z, Z, T, Z, "zupt", np.zeros(3), np.zeros(3), np.eye(3), accel_noise=-1.0
        ),
        "noise density",
    ),
    "noise arrays": (
        lambda _: KfNoise.from_log(Z, np.zeros((10, 2)), 100.0),
        r"\(N, 3\) accel and gyro",
    ),
    "gate probability": (lambda _: chi2_threshold(1.5, 3), r"gate probability must be in \(0, 1\)"),
    "preintegration lengths": (
        lambda _: PreintegratedImu().integrate(Z, Z, np.full(9, 0.01)),
        "preintegration: 10 accel, 10 gyro samples and 9",
    ),
    "RPE unit": (lambda _: rpe_pairs(_line(), 1.0, "km"), "RPE unit 'km'"),
    "RPE delta": (lambda _: rpe_pairs(_line(), 0.0, "m"), "RPE delta 0.0"),
    "no relations": (
        lambda _: relation_error(Z, Z, np.zeros(0, np.int64), np.zeros(0, np.int64)),
        "no relations",
    ),
    "scenario name": (lambda d: run_scenario("moon", 1.0, d / "out"), "unknown scenario 'moon'"),
    "scenario duration": (
        lambda d: run_scenario("room", 0.0, d / "out"),
        "duration_s must be positive",
    ),
    "quaternion shape": (
        lambda _: Trajectory.from_quat(np.arange(10), Z, Z),
        r"expected \(N, 4\) quaternions",
    ),
    "Allan series length": (lambda _: overlapped_adev(np.zeros(2), 100.0), "needs at least 3"),
    "no calibration": (
        lambda _: score_calibrations(_still_log(), [], 9.80665),
        "no calibration to score",
    ),
    "pose plan": (lambda _: OnlineCalibrator(np.zeros((5, 2)), None), "a pose plan of 5 poses"),
    "gyro without accel": (
        lambda _: _g_sensitive().correct_gyro(Z),
        "needs the accelerometer samples",
    ),
    # every LIO dataset gives m/s^2 and rad/s, and a calibration's correct() too
    "LIO IMU units": (
        lambda _: LioEstimator(LioConfig(), dataclasses.replace(_still_log(), accel_unit="g")),
        "the LIO needs the IMU in m/s",
    ),
    "LIO scan shape": (lambda _: clean_scan(_flat_scan(), 3), r"scan 3: expected points \(N, 3\)"),
    # a study file's scenario names are checked by ScenarioSpec, its estimators by check_study
    "study scene": (lambda _: scene("moon"), "unknown scenario 'moon'"),
    "study estimator": (lambda _: get_estimator("slam9000"), "unknown estimator 'slam9000'"),
    "study without cells": (
        lambda _: plan(StudyConfig.model_construct(claims=[], seeds=[0]), "s.yaml"),
        "s.yaml: the study has no cells",
    ),
    # a vio log without an IMU is refused when it is read, a vio run without it by its config
    "log study vio without IMU": (
        lambda _: _run_vio(cast(Any, SimpleNamespace(where="logs[0]")), None, None),
        "logs\\[0\\]: vio needs the log's IMU",
    ),
}


@pytest.mark.parametrize("case", list(MISUSE))
def test_api_misuse_is_a_value_error_not_an_input_error(case: str, tmp_path: Path) -> None:
    call, message = MISUSE[case]
    with pytest.raises(ValueError, match=message) as exc:
        call(tmp_path)
    assert not isinstance(exc.value, InputError), f"{case}: {exc.value!r} would exit 2 as bad input"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (
            lambda: Aiding(T, "zupt", np.where(np.arange(10)[:, None] == 7, np.nan, Z), 0.01),
            "measurement 7 is NaN",
        ),
        (lambda: Aiding(T[::-1], "zupt", Z, 0.01), "goes back in time"),
        (lambda: rpe_pairs(_line(), 1.5, "frames"), "whole number of frames"),
        (lambda: rpe_pairs(_line(3), 50.0, "m"), "gives no pair"),
        (lambda: allan(_still_log()), "an Allan analysis needs a long static log"),
        (lambda: KfNoise.from_log(Z[:2], Z[:2], 100.0), "at least 3 samples, got 2"),
    ],
)
def test_bad_data_and_reachable_options_stay_input_errors(
    call: Callable[[], object], message: str
) -> None:
    with pytest.raises(InputError, match=message):
        call()
