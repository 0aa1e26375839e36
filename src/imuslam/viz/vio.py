"""The visual-inertial odometry in a recording: per stereo pair (timelines ``sensor_time``, ``frame``)
the rectified left image ``camera/left`` with the tracks from the previous pair
``camera/left/tracks``, the motion fit's inliers ``camera/left/inliers`` and the other tracked features
``camera/left/outliers``, and the counts ``frame/tracked``, ``frame/inliers``; after the filter, on the
same clock, the fused and VO-only poses ``world/fused/body``, ``world/vo/body`` (and static
``world/fused/trajectory``, ``world/vo/trajectory``), the biases with their 1-sigma
``filter/bias/{accel,gyro}[_1sigma]``, and per update (timeline ``update``) the NIS of each kind
``filter/nis/<kind>`` with the gate ``filter/nis/<kind>/gate``; the ground truth aligned onto the fused
trajectory ``world/ground_truth``."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from imuslam.viz.recording import set_time, time_column

if TYPE_CHECKING:
    from imuslam.interfaces import Trajectory
    from imuslam.vio.pipeline import VioFrame, VioResult


class VioLogger:
    """The observer of :meth:`imuslam.vio.pipeline.VioPipeline.run` writing to ``rec``; images as JPEG
    (``jpeg_quality``), every ``image_every``-th pair."""

    def __init__(self, rec: Any, image_every: int = 1, jpeg_quality: int = 80) -> None:
        import rerun as rr

        self.rr, self.rec = rr, rec
        self.image_every, self.jpeg_quality = image_every, jpeg_quality
        self.n = 0
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    def __call__(self, frame: VioFrame) -> None:
        rr, rec = self.rr, self.rec
        set_time(rec, frame.t_ns, self.n, "frame")
        if self.n % self.image_every == 0:
            rec.log("camera/left", rr.Image(frame.left).compress(jpeg_quality=self.jpeg_quality))
        self.n += 1
        if frame.tracks is None:
            return
        uv0, uv1, inl = frame.tracks
        ok = np.isfinite(uv1[:, 0])
        rec.log("camera/left/tracks", rr.LineStrips2D(np.stack([uv0[ok], uv1[ok]], axis=1),
                                                       colors=[255, 200, 0], radii=0.5))  # fmt: skip
        is_in = np.zeros(len(uv1), bool)
        is_in[inl] = True
        rec.log("camera/left/inliers", rr.Points2D(uv1[is_in], colors=[40, 200, 40], radii=2.0))
        rec.log(
            "camera/left/outliers", rr.Points2D(uv1[ok & ~is_in], colors=[230, 40, 40], radii=2.0)
        )
        rec.log("frame/tracked", rr.Scalars(float(ok.sum())))
        rec.log("frame/inliers", rr.Scalars(float(len(inl))))

    def _track(self, path: str, tr: Trajectory, colour: tuple[int, int, int]) -> None:
        rr, rec = self.rr, self.rec
        rec.log(f"{path}/trajectory", rr.LineStrips3D([tr.p_w], colors=[colour]), static=True)
        rec.send_columns(f"{path}/body", indexes=[time_column(rr, tr.t_ns)],
                         columns=rr.Transform3D.columns(translation=tr.p_w, mat3x3=tr.R_w_b))  # fmt: skip

    def _series(self, path: str, t_ns: Any, v: Any, names: list[str]) -> None:
        rr, rec = self.rr, self.rec
        rec.log(path, rr.SeriesLines(names=names), static=True)
        rec.send_columns(path, indexes=[time_column(rr, t_ns)],
                         columns=rr.Scalars.columns(scalars=np.asarray(v, np.float64)))  # fmt: skip

    def finish(self, result: VioResult, truth: Trajectory | None = None) -> None:
        """The filter's output on the sensor clock (see the module's description)."""
        from scipy.stats import chi2

        rr, rec = self.rr, self.rec
        self._track("world/fused", result.fused, (255, 140, 0))
        self._track("world/vo", result.vo, (30, 120, 230))
        if len(result.bias_t_s):
            t = result.t_ref_ns + np.round(np.asarray(result.bias_t_s) * 1e9).astype(np.int64)
            for name, sl in (("accel", slice(0, 3)), ("gyro", slice(3, 6))):
                self._series(f"filter/bias/{name}", t, result.bias[:, sl], ["x", "y", "z"])
                self._series(
                    f"filter/bias/{name}_1sigma", t, result.bias_std[:, sl], ["x", "y", "z"]
                )
        gate = result.config.gate_prob
        for kind, st in result.gating.items():
            if not st.nis:
                continue
            seq = rr.TimeColumn("update", sequence=np.arange(len(st.nis)))
            rec.send_columns(f"filter/nis/{kind}", indexes=[seq],
                             columns=rr.Scalars.columns(scalars=np.asarray(st.nis, float)))  # fmt: skip
            if gate is not None:
                g = np.full(len(st.nis), float(chi2.ppf(gate, st.dof)))
                rec.send_columns(f"filter/nis/{kind}/gate", indexes=[seq],
                                 columns=rr.Scalars.columns(scalars=g))  # fmt: skip
        if truth is not None:
            from imuslam.viz.lio import log_truth

            log_truth(rr, rec, truth, result.fused)
