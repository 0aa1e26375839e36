"""LiDAR-inertial odometry: deskew, features, iterated error-state Kalman filter, map."""
