"""Recordings of a run for the rerun viewer (``--rrd`` / ``--viewer``, ``imuslam view``).

A layer above the estimators and below the CLI: the pipelines hand their per-step results to an
observer (``LioPipeline.run(observer)``, ``Slam2dPipeline.run(observer=...)``,
``VioPipeline.run(observer=...)``) and the loggers here turn them into rerun entities on the sensor's
own clock (timeline ``sensor_time``, the stamps of the data) and a step counter (``scan`` / ``frame``).
Nothing of rerun is imported until a recording is opened (:func:`imuslam.viz.recording.open_recording`).

Frames: ``world/...`` entities are in the estimate's world frame (w), metres; ``world/body`` is the
body (IMU) frame's pose, so ``world/body/scan`` holds the registered points in that frame.
"""
