"""The free-INS error budget of a study cell: its 'cell' figure is the cell's own ATE and the integrator
alone adds (almost) nothing."""

from __future__ import annotations

import numpy as np
import pytest

from imuslam.study.budget import ins_error_budget
from imuslam.study.cells import expand
from imuslam.study.config import parse_study
from imuslam.study.pipeline import run_cell


def test_budget_of_a_short_ins_cell_matches_the_cell() -> None:
    """Room, 20 s of alignment then 10 s of free INS, ideal IMU, Kalman alignment: the budget's 'cell'
    (RMS position error of every sample) equals the cell's ape_rmse_m (its 10 Hz poses, no
    alignment of the trajectories) to 3 %; a perfect IMU from the true attitude stays within 1 cm (the
    integrator's error, about 1 mm over 30 s in the full cell); each source alone is finite and the
    alignment leaves a heading error."""
    study = parse_study({"seeds": [0], "align": {"duration_s": 20.0}, "claims": [{
        "name": "c", "scenarios": [{"name": "room", "duration_s": 10.0}], "imu": ["ideal"],
        "alignment": ["kf"], "estimators": [{"name": "ins"}], "compare": "imu",
        "eval_align": "none"}]})  # fmt: skip
    cell = expand(study)[0]
    b = ins_error_budget(cell)
    row = run_cell(cell)
    assert row["status"] == "ok", row["error"]
    assert b["cell"] == pytest.approx(row["ape_rmse_m"], rel=0.03)
    assert b["perfect"] < 0.01
    assert b["cell"] > 10 * b["perfect"]
    assert all(np.isfinite(v) for v in b.values())
    assert abs(b["heading_err_deg"]) == pytest.approx(row["align_heading_err_deg"], rel=1e-6)
