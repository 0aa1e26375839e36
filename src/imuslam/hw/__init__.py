"""Real hardware: WitMotion serial IMU, servo gimbal, RPLIDAR."""
