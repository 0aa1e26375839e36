"""The online calibrator's session loop on the robot: an IMU's samples (a WitMotion on a serial port) fed to
the calibrator while it turns a gimbal (a servo gimbal) through the pose plan. The loop knows the devices
only by their protocols, so the hardware drivers (``imuslam.hw``) plug into it from above.

The sensor's samples carry the host's clock (epoch nanoseconds), so a session is started at the first
sample's time stamp, never at 0: the calibrator holds T_init only from the time the gimbal has arrived
at the first pose on that same clock.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from imuslam.imu.history import CalibrationHistory
from imuslam.imu.online import Event, OnlineCalibrator, OnlineConfig
from imuslam.interfaces.gimbal import Gimbal

FloatArray = NDArray[np.float64]


class SampleStream(Protocol):
    """What the loop needs of an IMU: :class:`imuslam.hw.witmotion.WitMotionImu` provides it."""

    def samples(self, rate_hz: float = 100.0) -> Iterator[tuple[int, FloatArray, FloatArray]]: ...


def run_online(
    imu: SampleStream,
    gimbal: Gimbal,
    plan_deg: FloatArray,
    config: OnlineConfig | None = None,
    history: CalibrationHistory | None = None,
    rate_hz: float = 100.0,
    on_event: Callable[[Event], None] | None = None,
    on_corrected: Callable[[int, FloatArray, FloatArray], None] | None = None,
    stop: Callable[[OnlineCalibrator], bool] | None = None,
) -> OnlineCalibrator:
    """Feed the IMU's samples to an :class:`OnlineCalibrator` that turns ``gimbal`` through ``plan_deg``:
    a first session when no calibration is in the history, another at each drift or schedule event. Runs
    until the IMU stops or ``stop(calibrator)`` is true; returns the calibrator."""

    def command(angles: FloatArray) -> float:
        target = (float(angles[0]), float(angles[1]))
        wait = gimbal.settle_time_s(target)
        gimbal.move_to(target)
        return wait

    cal = OnlineCalibrator(
        plan_deg,
        command,
        config,
        current=history.latest() if history is not None else None,
        history=history,
        rate_hz=rate_hz,
        on_corrected=on_corrected,
    )
    if cal.current is None:
        cal.start_session()  # at the first sample's time stamp
    seen = 0
    for t, a, w in imu.samples(rate_hz):
        cal.step(t, a, w)
        while seen < len(cal.events):
            e = cal.events[seen]
            seen += 1
            if on_event is not None:
                on_event(e)
            if e.kind in ("drift", "schedule"):
                cal.start_session(t)
        if stop is not None and stop(cal):
            break
    return cal
