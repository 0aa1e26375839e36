"""Simulator with ground truth: trajectories, IMU with its error model, LiDARs, stereo, odometry."""
