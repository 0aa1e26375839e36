"""A study of a user's own recorded log: the log, the estimator that runs on it, and the IMU of each run
(as recorded, corrected by a calibration file ``imuslam calibrate`` wrote, or corrupted on purpose
with seed 000's table-2 errors and corrected again). YAML keys equal the field names; an unknown key
is an error naming it. Relative paths are read from the study file's folder.

    name: backpack
    logs:
      - name: backpack
        path: ../../shared/data/cartographer_backpack_2d/b0-2014-07-21-12-42-53-short.bag
        estimator: map2d
        scan_topic: horizontal_laser_2d
        runs:
          - name: raw
          - name: calibrated
            calibration: calibration.yaml
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from imuslam.errors import InputError

LOG_ESTIMATORS = ("map2d", "vio", "lio")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class RunSpec(_Strict):
    """One run over the log: which IMU the estimator gets.

    calibration: a calibration YAML (``imuslam calibrate``), applied to the log's IMU; none: the IMU as
    recorded ("raw"). inject: corrupt the log's IMU (a copy in memory; the file is never touched) with
    seed 000's table-2 errors (misalignment, scale, bias) before anything else, to see what they cost.
    gimbal_calibration: correct the IMU with a calibration imuslam estimates from a simulated 40-pose
    gimbal session of a sensor with those errors (``gimbal_seed``: the session's noise), as the online
    calibrator would on the robot (``gimbal_method``).
    """

    name: str = Field(pattern=r"^[A-Za-z0-9_.+-]+$")
    calibration: str | None = None
    inject: Literal["seed000"] | None = None
    gimbal_calibration: Literal["seed000"] | None = None
    gimbal_seed: int = Field(0, ge=0, le=2**32 - 1)
    gimbal_method: Literal["online", "multipose"] = Field(
        "online",
        description="online: the online calibrator's start-up session, the 40 poses in the order "
        "`imuslam online` flies them; multipose: one offline multi-position fit of a 40-pose log",
    )
    use_imu: bool = Field(
        True,
        description="false: the estimator without the IMU (map2d, lio), what the IMU adds at all",
    )

    @model_validator(mode="after")
    def _one_calibration(self) -> RunSpec:
        if self.calibration is not None and self.gimbal_calibration is not None:
            raise ValueError(
                f"run '{self.name}': both calibration and gimbal_calibration; expected one of them"
            )
        if not self.use_imu and (self.inject or self.calibration or self.gimbal_calibration):
            raise ValueError(
                f"run '{self.name}': use_imu false with an IMU to corrupt or correct; expected one"
            )
        return self


class LogSpec(_Strict):
    """A recorded log, its estimator and the runs to compare."""

    name: str = Field(pattern=r"^[A-Za-z0-9_.+-]+$")
    path: str
    estimator: Literal["map2d", "vio", "lio"]
    format: Literal["auto", "carmen", "breezyslam", "bag", "sim"] = Field(
        "auto", description="map2d: the laser log's format"
    )
    scan_topic: str | None = None
    imu_topic: str | None = None
    points_topic: str | None = Field(None, description="lio bags: the PointCloud2 topic")
    odom_topic: str | None = None
    left_topic: str | None = Field(None, description="vio bags: the left image topic")
    right_topic: str | None = None
    camchain: str | None = Field(None, description="vio bags: a Kalibr camchain YAML")
    gt: str | None = Field(None, description="ground truth trajectory for ATE/RPE")
    gt_format: Literal["auto", "tum", "euroc"] = "auto"
    align: Literal["se3", "sim3", "yaw", "first"] = "se3"
    config: dict[str, Any] = Field(
        default_factory=dict, description="fields of the estimator's configuration"
    )
    reference: str | None = Field(
        None, description="the run the others' trajectories are compared with; default: the first"
    )
    radius_m: float | None = Field(
        None,
        gt=0,
        le=5,
        description="neighbourhood radius of the map sharpness; default 0.2 m "
        "in 2D, 0.3 m in 3D (Razlaw et al. 2015)",
    )
    runs: list[RunSpec] = Field(min_length=1)

    @model_validator(mode="after")
    def _runs(self) -> LogSpec:
        names = [r.name for r in self.runs]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"log '{self.name}': run names repeat: {', '.join(dup)}")
        if self.reference is not None and self.reference not in names:
            raise ValueError(
                f"log '{self.name}': reference '{self.reference}' is not a run ({', '.join(names)})"
            )
        return self

    @model_validator(mode="after")
    def _vio_imu(self) -> LogSpec:
        off = [r.name for r in self.runs if not r.use_imu]
        if off and self.estimator == "vio":
            raise ValueError(f"log '{self.name}': run '{off[0]}' without the IMU; vio fuses it")
        return self

    @property
    def reference_run(self) -> str:
        return self.reference or self.runs[0].name


class LogStudyConfig(_Strict):
    """A study over recorded logs (see the module docstring)."""

    name: str = "log study"
    logs: list[LogSpec] = Field(min_length=1)

    @model_validator(mode="after")
    def _unique(self) -> LogStudyConfig:
        names = [x.name for x in self.logs]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"log names repeat: {', '.join(dup)}")
        return self


def is_log_study(data: Any) -> bool:
    """A study file that names logs (not claims over the simulator)."""
    return isinstance(data, dict) and "logs" in data


def parse_log_study(data: Any, source: str, base: Path) -> LogStudyConfig:
    """Validate a log study; relative paths become paths from ``base`` (the study file's folder).
    The first problem is one InputError line naming the field."""
    from imuslam.study.config import validation_line

    try:
        st = LogStudyConfig.model_validate(data)
    except ValidationError as exc:
        raise InputError(
            f"{source}: {validation_line(exc, data, 'the study has no runs')}"
        ) from None

    def rel(p: str | None) -> str | None:
        return None if p is None else str(p if Path(p).is_absolute() else base / p)

    logs = []
    for lg in st.logs:
        runs = [r.model_copy(update={"calibration": rel(r.calibration)}) for r in lg.runs]
        logs.append(lg.model_copy(update={"path": rel(lg.path), "gt": rel(lg.gt),
                                          "camchain": rel(lg.camchain), "runs": runs}))  # fmt: skip
    return st.model_copy(update={"logs": logs})
