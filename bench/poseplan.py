"""Pose plans: predicted gain of ordering seed 000's 40 poses for the gyroscope, and the shortest plan that
meets a target 10 %, 30 % and 50 % looser than the 40-pose plan's predicted 1-sigma (seed 000's gimbal,
0.088 deg, and a PCA9685 hobby-servo gimbal, 0.44 deg per count).

Run: .venv/bin/python bench/poseplan.py
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from rich.console import Console
from rich.table import Table

from imuslam.imu.poseplan import PlanModel, optimise_order, plan_for_target
from imuslam.sim.multipose import sphere_plan_deg
from imuslam.threads import configure_process


def main() -> None:
    table = Table(title="Pose plans (predicted 1-sigma, as the calibration reports it)")
    for c in ("gimbal", "plan", "poses", "gyro std vs 40-pose lattice order", "time [s]"):
        table.add_column(c, justify="right")
    for name, res in (("seed 000 (0.088 deg)", None), ("PCA9685 servo (0.44 deg)", 0.44)):
        model = (
            PlanModel.seed000() if res is None else replace(PlanModel.seed000(), resolution_deg=res)
        )
        std40 = sphere_plan_deg(40)
        sa0, sg0 = model.predicted_std(std40)
        t0 = time.perf_counter()
        opt = optimise_order(model, std40, target_gyro_std=sg0)
        _, sg1 = model.predicted_std(opt)
        gain = 1 - sg1 / sg0
        table.add_row(name, "40, ordered for the gyro", "40", f"lower by {100 * gain.min():.0f}-{100 * gain.max():.0f} %",
                      f"{time.perf_counter() - t0:.1f}")  # fmt: skip
        for loose in (1.1, 1.3, 1.5):
            t0 = time.perf_counter()
            plan = plan_for_target(
                model, loose * sa0, loose * sg0, min_poses=12, max_poses=40, iterations=500
            )
            _, sg = model.predicted_std(plan)
            table.add_row(name, f"target {100 * (loose - 1):.0f} % looser", str(len(plan)),
                          f"{np.max(sg / sg0):.2f}x at most", f"{time.perf_counter() - t0:.1f}")  # fmt: skip
    Console().print(table)


if __name__ == "__main__":
    configure_process()  # the command line's thread defaults, before numba's first parallel kernel
    main()
