"""imuslam: IMU calibration without external equipment, INS alignment and IMU-aided SLAM.

Frames (one letter each, used in every name ``R_a_b`` / ``T_a_b`` that maps a point from frame b into
frame a, ``p_a = R_a_b @ p_b``):

    w world      i IMU        b body       l LiDAR
    c camera     n navigation g gimbal     s sensor (raw, non-orthogonal IMU axes)

Units are SI unless a name says otherwise (``_deg``, ``_ns``, ``_dps``). Time is integer ``t_ns`` at
the I/O boundary and float seconds inside the maths. Quaternions are Hamilton, scalar first
(``quat_wxyz``) everywhere inside the package; ``io/`` converts from and to other orders.
Lie tangent vectors are ordered rotation first, then translation (see ``imuslam.geometry``).

Layers, lowest first; a module never imports a higher one:
geometry -> io -> sim -> imu -> ins -> lio / vio / slam2d -> eval -> hw -> config -> cli.
"""

__version__ = "0.1.0"
