"""imuslam: IMU calibration without external equipment, INS alignment and IMU-aided SLAM.

Frames (one letter each, used in every name ``R_a_b`` / ``T_a_b`` that maps a point from frame b into
frame a, ``p_a = R_a_b @ p_b``):

    w world      i IMU        b body       l LiDAR
    c camera     n navigation g gimbal     s sensor (raw, non-orthogonal IMU axes)

Units are SI unless a name says otherwise (``_deg``, ``_ns``, ``_dps``). Time is integer ``t_ns`` at
the I/O boundary and float seconds inside the maths. Quaternions are Hamilton, scalar first
(``quat_wxyz``) everywhere inside the package; ``io/`` converts from and to other orders.
Lie tangent vectors are ordered rotation first, then translation (see ``imuslam.geometry``).

Layers, lowest first; a module never imports a higher one (``lint-imports`` checks it):
geometry -> interfaces / errors -> io / config -> sim / imu / ins / hw -> lio / vio / slam2d -> eval ->
study -> cli (docs/architecture.md).

Threads: numba's parallel kernels run on OpenMP (GNU libgomp), whose idle threads spin by default. When
other processes hold the cores (a study runs several workers per machine) the spinning thread competes
with them and a 0.12 s calibration call takes 0.36 s. Importing imuslam therefore makes OpenMP threads
wait passively (``OMP_WAIT_POLICY=PASSIVE``) unless the variable is already set: the two-thread gain is
kept on an idle machine and a busy one costs about what one thread would (``bench/threads.py``). It
takes effect only if no OpenMP runtime was loaded before imuslam (libgomp reads it once, when loaded).

OpenBLAS (numpy's and scipy's linear algebra) starts one thread per core, and its idle threads spin too.
The matrices here are small (a calibration's normal equations are about 100 x 100, a filter's 18 x 18),
so a second thread gains nothing and, with the other core busy, the xsens calibration costs 2.5x the CPU
time and 2x the wall time. Importing imuslam therefore sets ``OPENBLAS_NUM_THREADS=1`` unless it is set
(again only if numpy was not imported before imuslam; ``bench/threads.py`` measures both).
"""

import os as _os

_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"
