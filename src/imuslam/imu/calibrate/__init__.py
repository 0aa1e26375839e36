"""Multi-position IMU calibration without external equipment (Tedaldi, Pretto, Menegatti, ICRA 2014).

1. Static detection with a threshold sweep (``imu/static.py``).
2. Accelerometer: Levenberg-Marquardt on the gravity-norm residual ``r = g - |T K (a_S ± b)|`` over the
   static samples (Tedaldi 2014, eq. 10; the seed's eq. 12 squares both norms, which has the same
   minimiser for small residuals), with an analytic Jacobian. The threshold kept is the one with the
   lowest residual per sample.
3. Gyroscope: bias = mean over the initial still period; misalignment and scale by integrating the
   corrected rate (RK4 on the quaternion, eq. 14) between consecutive static intervals and comparing the
   predicted gravity direction with the measured one (eq. 13): ``r = R^T u_0 - u_1``.
4. Covariance ``s^2 (J^T J)^-1`` at the solution with ``s^2`` the residual variance, and an
   observability verdict.
5. ``method="joint"`` (the default): steps 2-3 only start a joint weighted least squares of both triads,
   the gyro bias and its g-sensitivity over every pose's accelerometer mean, every rotation's predicted
   gravity direction and every pose's rate at rest (``imu/joint.py``), whose covariance replaces theirs.
   Each residual is weighted by the noise measured in the initial still period; the g-sensitivity and a
   linear accelerometer bias drift are fitted and kept only when their Wald test is significant.
   ``method="tedaldi"`` stops after step 4 (imu_tk's result, for reproduction).

The stages, each a module with typed records: ``run.still_period`` (the log's checks and the still
period) -> ``accel.fit_accelerometer`` (static detection sweep and the norm fit, ``AccelFit``) ->
``gyro.fit_gyroscope`` (``GyroFit``) -> ``refine.refine_jointly`` (the joint method, ``Estimate``) ->
``run.calibration_of`` (covariance and observability verdict) -> ``CalibrationResult``.
"""

from imuslam.imu.calibrate.accel import accel_initial_guess, accel_residual_jacobian
from imuslam.imu.calibrate.config import CalibrationConfig, CalibrationResult, SweepRow
from imuslam.imu.calibrate.gyro import (
    extend_to_motion,
    extend_to_rest,
    gyro_residual_jacobian,
    gyro_residuals,
    motion_compensated_means,
)
from imuslam.imu.calibrate.run import calibrate

__all__ = [
    "CalibrationConfig",
    "CalibrationResult",
    "SweepRow",
    "accel_initial_guess",
    "accel_residual_jacobian",
    "calibrate",
    "extend_to_motion",
    "extend_to_rest",
    "gyro_residual_jacobian",
    "gyro_residuals",
    "motion_compensated_means",
]
