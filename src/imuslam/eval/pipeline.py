"""``EvalPipeline(reference, estimate, config).run() -> EvalResult``, and the one way its results folder
is written (``metrics.json``, ``config.yaml``, ``estimate_aligned.tum``, plots), as KISS-ICP's
``OdometryPipeline`` drives an estimator and evo's ``Result`` carries metrics with their trajectories."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from imuslam.eval.align import AlignMethod
from imuslam.eval.metrics import KITTI_LENGTHS, EvalResult, evaluate
from imuslam.interfaces.trajectory import Trajectory
from imuslam.io.results import write_results


class EvalConfig(BaseModel):
    """How an estimate is scored (the fields of ``imuslam eval``)."""

    model_config = ConfigDict(extra="forbid")

    align: AlignMethod = "se3"
    rpe_delta: float = Field(1.0, gt=0)
    rpe_unit: Literal["frames", "m"] = "frames"
    max_diff_s: float = Field(0.01, gt=0, description="association: max time difference, s")
    kitti: bool = Field(False, description="also KITTI drift over 100..800 m segments")
    by_index: bool = Field(False, description="pair poses by index (KITTI files without times)")


class EvalPipeline:
    """Score ``estimate`` against ``reference``: associate, align, APE / RPE / KITTI drift."""

    def __init__(
        self, reference: Trajectory, estimate: Trajectory, config: EvalConfig | None = None
    ) -> None:
        self.reference = reference
        self.estimate = estimate
        self.config = config or EvalConfig()

    def run(self) -> EvalResult:
        c = self.config
        return evaluate(
            self.reference,
            self.estimate,
            c.align,
            c.rpe_delta,
            c.rpe_unit,
            c.max_diff_s,
            KITTI_LENGTHS if c.kitti else None,
            by_index=c.by_index,
        )

    def save(self, result: EvalResult, out: str | Path, plots: bool = True, **inputs: str) -> Path:
        """The results folder, all or nothing: ``config.yaml`` (``inputs`` and the config),
        ``metrics.json``, ``estimate_aligned.tum`` and, with ``plots``, trajectories.png and ape.png."""

        def extra(folder: Path) -> None:
            if plots:
                from imuslam.eval.plots import plot_evaluation

                assert result.reference is not None and result.estimate_aligned is not None
                plot_evaluation(result, result.reference, result.estimate_aligned, folder)

        trajs = (
            {} if result.estimate_aligned is None else {"estimate_aligned": result.estimate_aligned}
        )
        return write_results(
            out,
            config={**inputs, **self.config.model_dump(mode="json")},
            metrics=result,
            trajectories=trajs,
            extra=extra,
        )
