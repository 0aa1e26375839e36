"""Trajectory association, alignment (Umeyama, yaw-only), ATE/RPE, reports and plots."""
