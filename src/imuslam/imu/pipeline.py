"""``CalibratePipeline(dataset, config).run() -> CalibrateOutput``: multi-position calibration of a log
with its cross-validation, and the results folder through the one writer (``io.results.write_results``),
as ``eval.pipeline.EvalPipeline`` does.

The two steps are also callable one by one (``calibrate()`` then ``cross_validate(result)``) so a
command prints the calibration before the cross-validation's refits start.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from imuslam.imu.calibrate import CalibrationConfig, CalibrationResult, calibrate
from imuslam.imu.model import ACCEL_PARAM_NAMES, GYRO_PARAM_NAMES
from imuslam.interfaces.imu import ImuLog
from imuslam.interfaces.sources import ImuSource

if TYPE_CHECKING:  # the cross-validation (and its pose scorer) loads only when folds are asked for
    from imuslam.imu.crossval import CrossValidation


@dataclass
class CalibrateOutput:
    """The calibration and, when asked for, its k-fold cross-validation over the static poses."""

    result: CalibrationResult
    cv: CrossValidation | None = None

    def metrics(self) -> dict[str, Any]:
        """What ``metrics.json`` holds: every parameter with its 1-sigma, the fit, the held-out score."""
        r, c = self.result, self.result.calibration
        m: dict[str, Any] = {
            "accel": {n: {"value": float(v), "std": float(s)}
                      for n, v, s in zip(ACCEL_PARAM_NAMES, c.accel_params, r.std_accel, strict=True)},
            "gyro": {n: {"value": float(v), "std": float(s)}
                     for n, v, s in zip(GYRO_PARAM_NAMES, c.gyro_params, r.std_gyro, strict=True)},
            "accel_unit": c.accel_unit, "gyro_unit": c.gyro_unit, "gyro_bias": c.gyro.b,
            "threshold_multiple": r.k, "static_intervals": len(r.intervals),
            "accel_rms_m_s2": r.accel_rms, "gyro_direction_rms_deg": r.gyro_rms_deg,
            "poorly_determined": r.poorly_determined, "warnings": r.warnings, "timings_s": r.timings_s,
        }  # fmt: skip
        if self.cv is not None:
            cv = self.cv
            m["cross_validation"] = {
                "folds": cv.k_folds, "poses": len(cv.poses), "method": cv.method,
                "norm_fit_rms_m_s2": cv.fit_norm_rms, "norm_rms_m_s2": cv.norm_rms,
                "norm_worst_m_s2": cv.norm_worst, "direction_fit_rms_deg": cv.fit_direction_rms_deg,
                "direction_rms_deg": cv.direction_rms_deg, "direction_worst_deg": cv.direction_worst_deg,
            }  # fmt: skip
        return m


class CalibratePipeline:
    """Calibrate ``dataset`` (an :class:`ImuLog` in raw or SI units, or an ``ImuSource``) with ``config``,
    then cross-validate over ``cv_folds`` folds of its static poses (0: none)."""

    def __init__(
        self,
        dataset: ImuLog | ImuSource,
        config: CalibrationConfig | None = None,
        cv_folds: int = 5,
    ) -> None:
        self.log = dataset if isinstance(dataset, ImuLog) else dataset.imu()
        self.config = config or CalibrationConfig()
        self.cv_folds = cv_folds

    def calibrate(self) -> CalibrationResult:
        return calibrate(self.log, self.config)

    def cross_validate(self, result: CalibrationResult) -> CrossValidation | None:
        if not self.cv_folds:
            return None
        from imuslam.imu.crossval import cross_validate

        return cross_validate(
            self.log, self.config, result.intervals, self.cv_folds, result.calibration
        )

    def run(self) -> CalibrateOutput:
        res = self.calibrate()
        return CalibrateOutput(res, self.cross_validate(res))

    def save(
        self,
        output: CalibrateOutput,
        out: str | Path,
        plots: bool = True,
        extra_html: str = "",
        truth_accel: np.ndarray | None = None,
        truth_gyro: np.ndarray | None = None,
    ) -> Path:
        """The results folder, all or nothing: ``config.yaml`` (the effective CalibrationConfig, loadable
        with ``--config``), ``metrics.json``, ``calibration.yaml``, imu_tk's ``acc.calib`` /
        ``gyro.calib`` and, with ``plots``, the figures and ``report.html``."""
        from imuslam.io.results import write_results

        res = output.result

        def extra(folder: Path) -> None:
            c = res.calibration
            c.save_yaml(folder / "calibration.yaml")
            c.export_imutk(folder / "acc.calib", folder / "gyro.calib")
            if plots:
                from imuslam.imu.report import write_report

                write_report(res, self.log, folder, truth_accel, truth_gyro, cv=output.cv,
                             extra_html=extra_html)  # fmt: skip

        return write_results(out, config=res.config, metrics=output.metrics(), extra=extra)
