"""Built-in studies: ``imuslam study --quick`` (a few cells, a couple of minutes on two cores; 10 seeds
first, 10 more where a pair is not resolved)."""

from __future__ import annotations

from typing import Any

QUICK: dict[str, Any] = {
    "name": "quick",
    "seeds": 10,
    "align": {"duration_s": 60.0},
    "claims": [
        {
            "name": "alignment_ins",
            "seed_doc": "001",
            "statement": "RWNN alignment beats strong tracking, which beats Kalman, which beats none "
            "(free INS after the alignment window, online-calibrated IMU)",
            "scenarios": [{"name": "street", "duration_s": 30.0}],
            "imu": ["online"],
            "alignment": ["none", "kf", "stkf", "rwnn"],
            "estimators": [{"name": "ins"}],
            "compare": "alignment",
            "expect": ["rwnn", "stkf", "kf", "none"],
            "metric": "ape_rmse_m",
            "eval_align": "none",
            "practical_bound": 0.1,
            "reason": "10 cm after 30 s of free inertial navigation: a twentieth of a street lane",
            "max_seeds": 20,
        },
        {
            "name": "calibration_ins",
            "seed_doc": "000",
            "statement": "a current calibration beats a stale one, which beats none "
            "(free INS after a Kalman alignment)",
            "scenarios": [{"name": "street", "duration_s": 30.0}],
            "imu": ["ideal", "online", "offline", "raw"],
            "alignment": ["kf"],
            "estimators": [{"name": "ins"}],
            "compare": "imu",
            "expect": ["online", "offline", "raw"],
            "metric": "ape_rmse_m",
            "eval_align": "none",
            "practical_bound": 0.1,
            "reason": "10 cm after 30 s of free inertial navigation: a twentieth of a street lane",
            "max_seeds": 20,
        },
    ],
}
