"""2D scan matching with IMU and wheel odometry, occupancy grid."""
