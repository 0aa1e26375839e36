"""``OnlinePipeline(dataset, config).run() -> OnlineOutput``: online calibration with a 2-axis gimbal,
on a simulated robot (:class:`SimulatedRobot`) or on the robot's devices (:class:`RobotDevices`), and
its results through the one writer (``io.results.write_results``), as ``eval.pipeline.EvalPipeline``.

The calibration history (``<history>/``) is written as the run goes, version by version (a robot that
stops keeps what it calibrated); ``save`` writes the run's summary beside it all or nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from imuslam.imu.calibrate import CalibrationConfig
from imuslam.imu.history import CalibrationHistory
from imuslam.imu.online import Event, OnlineConfig
from imuslam.imu.poseplan import PlanModel, optimise_order
from imuslam.interfaces.imu import ImuLog

FloatArray = NDArray[np.float64]
SEED_POSES = 40  # seed 000's pose count
SEED_T_INIT_S = 50.0  # seed 000's initial still period, s


class OnlineRunConfig(BaseModel):
    """The settings of an online run (the options of ``imuslam online``)."""

    model_config = ConfigDict(extra="forbid")

    poses: int = Field(SEED_POSES, ge=12, le=200, description="gimbal poses per session")
    t_init_s: float = Field(SEED_T_INIT_S, gt=0, le=600, description="initial still period, s")
    rate_hz: float = Field(100.0, gt=0, le=1000, description="IMU output rate, Hz")
    plan_iterations: int = Field(1000, ge=0, description="pose-order optimisation iterations")


@dataclass
class SimulatedRobot:
    """A simulated robot whose IMU errors drift (seed 000's errors at the start), for ``duration_s``."""

    duration_s: float = 3600.0
    drift_accel: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 0.05]))
    drift_gyro: FloatArray = field(default_factory=lambda: np.full(3, 0.001))
    seed: int = 0


@dataclass
class RobotDevices:
    """The robot's devices: an IMU source with ``read`` (e.g. ``hw.witmotion.WitMotionImu``) and a
    gimbal (``hw.gimbal.Pca9685Gimbal``); the run lasts until the IMU stops or Ctrl-C."""

    imu: Any
    gimbal: Any


@dataclass
class OnlineOutput:
    """The pose plan, the calibrator's events, the history's versions, and on a robot the corrected IMU.
    ``predicted`` holds the plan's predicted 1-sigma beside seed 000's 40 poses (shorter plans only)."""

    plan_deg: FloatArray
    events: list[Event]
    versions: list[int]
    predicted: tuple[FloatArray, FloatArray] | None = None
    corrected: ImuLog | None = None
    sessions: list[tuple[float, float]] = field(default_factory=list)

    def metrics(self) -> dict[str, Any]:
        kinds = [e.kind for e in self.events if e.kind != "command"]
        return {
            "poses": len(self.plan_deg), "versions": self.versions, "sessions_s": self.sessions,
            "counts": {k: kinds.count(k) for k in sorted(set(kinds))},
            "events": [{"t_s": e.t_ns * 1e-9, "kind": e.kind, "detail": e.detail}
                       for e in self.events if e.kind != "command"],
        }  # fmt: skip


class OnlinePipeline:
    """Plan the gimbal poses, then calibrate, monitor drift and recalibrate on ``dataset``."""

    def __init__(
        self,
        dataset: SimulatedRobot | RobotDevices,
        config: OnlineRunConfig | None = None,
        history: str | Path = "online_out/history",
    ) -> None:
        self.dataset = dataset
        self.config = config or OnlineRunConfig()
        self.history = CalibrationHistory(Path(history))

    def plan(self) -> tuple[PlanModel, FloatArray]:
        """The pose plan (deg), ordered for the gimbal (at the angles its servos can reach)."""
        from imuslam.sim.multipose import sphere_plan_deg

        model = PlanModel.seed000()
        if isinstance(self.dataset, RobotDevices):
            model = replace(model, resolution_deg=self.dataset.gimbal.resolution_deg)
        c = self.config
        return model, optimise_order(model, sphere_plan_deg(c.poses), iterations=c.plan_iterations)

    def predicted(self, model: PlanModel, plan: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(18,) predicted 1-sigma of the accel + gyro parameters with ``plan`` and with seed 000's plan."""
        from imuslam.sim.multipose import sphere_plan_deg

        sa, sg = model.predicted_std(plan)
        seed = optimise_order(model, sphere_plan_deg(SEED_POSES), iterations=1000)
        sa40, sg40 = model.predicted_std(seed)
        return np.concatenate([sa, sg]), np.concatenate([sa40, sg40])

    def run(
        self,
        on_event: Callable[[Event], None] | None = None,
        on_plan: Callable[[FloatArray, tuple[FloatArray, FloatArray] | None], None] | None = None,
    ) -> OnlineOutput:
        """Run to the end (simulated) or until the IMU stops or Ctrl-C (robot). ``on_plan(plan,
        predicted)`` sees the pose plan before the first session; ``on_event`` each event of the robot
        as it happens."""
        c, ds = self.config, self.dataset
        cfg = OnlineConfig(
            calibration=CalibrationConfig(t_init_s=c.t_init_s, accel_bias_drift=True)
        )
        model, plan = self.plan()
        pred = self.predicted(model, plan) if c.poses < SEED_POSES else None
        if on_plan is not None:
            on_plan(plan, pred)
        if isinstance(ds, SimulatedRobot):
            from imuslam.imu.online_sim import Drift, run_simulated_robot

            drift = Drift(np.asarray(ds.drift_accel, float), np.asarray(ds.drift_gyro, float))
            rng = np.random.default_rng(ds.seed)
            run = run_simulated_robot(plan, ds.duration_s, drift, rng, cfg, self.history)
            return OnlineOutput(plan, list(run.calibrator.events), self.history.versions(), pred,
                                sessions=list(run.sessions))  # fmt: skip
        from imuslam.imu.online_session import run_online

        buf_t: list[int] = []
        buf: list[FloatArray] = []

        def keep(t: int, a: FloatArray, w: FloatArray) -> None:
            buf_t.append(t)
            buf.append(np.concatenate([a, w]))

        events: list[Event] = []

        def note(e: Event) -> None:
            events.append(e)
            if on_event is not None:
                on_event(e)

        try:
            run_online(ds.imu, ds.gimbal, plan, cfg, self.history, c.rate_hz,
                       on_event=note, on_corrected=keep)  # fmt: skip
        except KeyboardInterrupt:
            pass
        x = np.array(buf).reshape(-1, 6)
        corrected = ImuLog(np.array(buf_t, dtype=np.int64), x[:, :3], x[:, 3:]) if buf else None
        return OnlineOutput(plan, events, self.history.versions(), pred, corrected)

    def save(self, output: OnlineOutput, out: str | Path, **inputs: Any) -> Path:
        """``config.yaml`` (``inputs`` and the config), ``metrics.json`` (events, versions) and, on a
        robot, ``corrected_imu.mcap``, all or nothing; the history beside them is kept as it is."""
        from imuslam.io.results import write_results

        def extra(folder: Path) -> None:
            if output.corrected is not None:
                from imuslam.io.rosbag import write_imu_bag

                write_imu_bag(output.corrected, folder / "corrected_imu.mcap")

        return write_results(
            out,
            config={**inputs, **self.config.model_dump(mode="json")},
            metrics=output.metrics(),
            extra=extra,
        )
