"""Write a rerun blueprint (a viewer layout) for a ``lio`` recording: the 3D world large on the left
(map, trajectory, ground truth, the current scan), three of the per-scan figures on the right, the
side panels folded and the time cursor at the end of the run. The layout of ``lio.png``:

    python docs/viewer/lio_blueprint.py lio.rbl
    rerun lio_run.rrd lio.rbl

``--eye X,Y,Z`` and ``--target X,Y,Z`` (metres, the recording's world frame) place the 3D camera; the
defaults frame the 20 s simulated street (``imuslam simulate street --duration 20``).
"""

from __future__ import annotations

import argparse

import rerun.blueprint as rrb


def vec3(text: str) -> list[float]:
    values = [float(v) for v in text.split(",")]
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z (three numbers), got {text!r}")
    return values


def lio_blueprint(eye: list[float], target: list[float]) -> rrb.Blueprint:
    world = rrb.Spatial3DView(
        origin="world",
        name="map, trajectory (orange), ground truth (grey)",
        eye_controls=rrb.EyeControls3D(position=eye, look_target=target, eye_up=[0.0, 0.0, 1.0]),
    )
    figures = rrb.Vertical(
        rrb.TimeSeriesView(origin="scan/residual_rms_m", name="residual RMS per scan (m)"),
        rrb.TimeSeriesView(origin="scan/points_registered", name="points registered per scan"),
        rrb.TimeSeriesView(origin="imu/raw/gyro", name="raw gyro (rad/s)"),
    )
    return rrb.Blueprint(
        rrb.Horizontal(world, figures, column_shares=[2.2, 1.0]),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline="sensor_time", play_state="following"),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="the blueprint file to write (.rbl)")
    parser.add_argument("--eye", type=vec3, default=[-30.0, -65.0, 125.0])
    parser.add_argument("--target", type=vec3, default=[4.0, 38.0, 0.0])
    args = parser.parse_args()
    # "imuslam" is the application id of imuslam's recordings: the viewer applies the layout to them
    lio_blueprint(args.eye, args.target).save("imuslam", args.out)


if __name__ == "__main__":
    main()
