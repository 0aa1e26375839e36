"""Strapdown mechanisation and INS alignment (coarse, Kalman, strong tracking, RWNN)."""
