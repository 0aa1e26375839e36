"""Cells: one simulate -> calibrate -> align -> estimate -> evaluate run each, named by a content hash.

A cell's hash covers everything that decides its numbers (scenario, durations, IMU condition, drift,
alignment settings, estimator and options, evaluation, seed, and :data:`CELL_FORMAT`), not the claim
it serves, so a cell two claims share runs once. Random numbers come from hashes too:
- the world (trajectory noise, IMU noise, position fixes, the initial attitude error, the other sensors)
  from the scene part only (scenario, durations, seed), so the levels a claim compares see the same
  noise (common random numbers: differences are paired);
- the calibration logs from (seed, age of the errors);
- the estimator's own randomness (RANSAC...) from the cell hash.
"""

from __future__ import annotations

import hashlib
import json
from itertools import product
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict

from imuslam.study.config import AlignSpec, DriftSpec, EstimatorSpec, ScenarioSpec, StudyConfig

CELL_FORMAT = (
    1  # bump when a change of the cell pipeline changes its numbers (invalidates the cache)
)


class Cell(BaseModel):
    """Everything one run needs; sent to the workers as is."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    claim: str
    scenario: ScenarioSpec
    imu: str
    alignment: str
    estimator: EstimatorSpec
    seed: int
    drift: DriftSpec
    align: AlignSpec
    eval_align: str

    def content(self) -> dict[str, Any]:
        d = self.model_dump(mode="json", exclude={"claim"})
        d["estimator"].pop("label", None)
        d["format"] = CELL_FORMAT
        if self.imu in ("ideal",):
            d.pop("drift")  # the ideal IMU has no systematic errors to drift
        return d

    @property
    def key(self) -> str:
        """Content hash (16 hex digits)."""
        return digest(self.content())

    def world_seed(self) -> int:
        return _seed(
            {
                "scenario": self.scenario.model_dump(mode="json"),
                "align": self.align.model_dump(mode="json"),
                "seed": self.seed,
            }
        )

    def calibration_seed(self, age_h: float) -> int:
        return _seed({"gimbal": self.seed, "age_h": age_h})

    def estimator_seed(self) -> int:
        return int(self.key, 16) % (2**63)

    def world_rng(self, stream: str) -> np.random.Generator:
        """An independent generator per named stream of the scene ('imu', 'fixes', 'lidar', ...)."""
        return np.random.default_rng([self.world_seed(), _seed({"stream": stream})])

    @property
    def label(self) -> dict[str, Any]:
        """The row's factor columns."""
        return {
            "claim": self.claim,
            "scenario": self.scenario.name,
            "duration_s": self.scenario.duration_s,
            "imu": self.imu,
            "alignment": self.alignment,
            "estimator": self.estimator.name,
            "variant": self.estimator.variant,
            "seed": self.seed,
        }


def digest(d: Any) -> str:
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


def _seed(d: Any) -> int:
    return int(digest(d), 16) % (2**63)


def expand(study: StudyConfig, seeds: dict[str, list[int]] | None = None) -> list[Cell]:
    """Every cell of every claim, in a fixed order (claims, scenarios, imu, alignment, estimators, seeds):
    over ``seeds[claim]`` where given, else over the claim's first seeds (``ClaimSpec.first_seeds``)."""
    cells = []
    for c in study.claims:
        these = (seeds or {}).get(c.name) or c.first_seeds(study.seeds)
        for sc, imu, al, est, seed in product(c.scenarios, c.imu, c.alignment, c.estimators, these):
            cells.append(
                Cell(
                    claim=c.name,
                    scenario=sc,
                    imu=imu,
                    alignment=al,
                    estimator=est,
                    seed=seed,
                    drift=study.drift,
                    align=c.align or study.align,
                    eval_align=c.eval_align,
                )  # fmt: skip
            )
    return cells
