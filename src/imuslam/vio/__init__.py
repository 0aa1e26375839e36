"""Stereo visual odometry and its EKF fusion with the IMU."""
