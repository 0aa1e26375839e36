"""IMU error model, static detection, calibration, Allan variance and the online calibrator."""
