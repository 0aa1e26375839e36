"""APE and RPE equal evo's on evo's own test data (evo is a test-only dependency, run in the same test)."""

import copy
import functools
from pathlib import Path

import pytest
from evo.core import metrics, sync
from evo.tools import file_interface

from imuslam.eval.metrics import evaluate
from imuslam.io.trajectory import read_euroc_gt, read_kitti, read_tum

CASES = {
    "kitti_orb": ("KITTI_00_gt.txt", "KITTI_00_ORB.txt", "kitti"),
    "kitti_sptam": ("KITTI_00_gt.txt", "KITTI_00_SPTAM.txt", "kitti"),
    "tum_fr2_desk": ("fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt", "tum"),
    "euroc_v102": ("V102_groundtruth.csv", "V102.txt", "euroc"),
}


@functools.cache
def _evo_aligned(d: Path, case: str, correct_scale: bool):  # type: ignore[no-untyped-def]
    """evo's reference and aligned estimate, and its APE statistics: the same for every RPE delta, so
    computed once per (case, alignment) in a test session (evo's metrics do not modify the poses)."""
    gt, est, kind = CASES[case]
    if kind == "kitti":
        ref = file_interface.read_kitti_poses_file(d / gt)
        e = file_interface.read_kitti_poses_file(d / est)
    else:
        ref = (
            file_interface.read_euroc_csv_trajectory(d / gt)
            if kind == "euroc"
            else file_interface.read_tum_trajectory_file(d / gt)
        )
        e = file_interface.read_tum_trajectory_file(d / est)
        ref, e = sync.associate_trajectories(ref, e, max_diff=0.01)
    e = copy.deepcopy(e)
    e.align(ref, correct_scale=correct_scale)
    apes = {}
    for name, rel in (
        ("t", metrics.PoseRelation.translation_part),
        ("r", metrics.PoseRelation.rotation_angle_deg),
    ):
        ape = metrics.APE(rel)
        ape.process_data((ref, e))
        apes[name] = ape.get_all_statistics()
    return ref, e, apes


def _evo(d: Path, case: str, correct_scale: bool, delta: float, unit: "metrics.Unit"):  # type: ignore[no-untyped-def]
    ref, e, apes = _evo_aligned(d, case, correct_scale)
    out = {}
    for name, rel in (
        ("t", metrics.PoseRelation.translation_part),
        ("r", metrics.PoseRelation.rotation_angle_deg),
    ):
        rpe = metrics.RPE(rel, delta=delta, delta_unit=unit, all_pairs=False)
        rpe.process_data((ref, e))
        out[name] = (apes[name], rpe.get_all_statistics())
    return out, ref.num_poses


def _ours(d: Path, case: str, align: str, delta: float, unit: str):  # type: ignore[no-untyped-def]
    gt, est, kind = CASES[case]
    if kind == "kitti":
        return evaluate(read_kitti(d / gt), read_kitti(d / est), align, delta, unit, by_index=True)  # type: ignore[arg-type]
    ref = read_euroc_gt(d / gt) if kind == "euroc" else read_tum(d / gt)
    return evaluate(ref, read_tum(d / est), align, delta, unit, max_diff_s=0.01)  # type: ignore[arg-type]


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("align", ["se3", "sim3"])
@pytest.mark.parametrize(("delta", "unit"), [(1, "frames"), (10, "frames"), (5.0, "m")])
def test_matches_evo(shared_data: Path, case: str, align: str, delta: float, unit: str) -> None:
    d = shared_data / "evo_testdata"
    if unit == "m" and case.startswith("tum"):
        delta = 0.2  # the desk sequence is ~18 m long
    evo_unit = metrics.Unit.frames if unit == "frames" else metrics.Unit.meters
    ref_stats, n = _evo(d, case, align == "sim3", delta, evo_unit)
    res = _ours(d, case, align, delta, unit)
    assert res.n_pairs == n
    for key, ours in (
        ("t", (res.ape_trans, res.rpe_trans)),
        ("r", (res.ape_rot_deg, res.rpe_rot_deg)),
    ):
        for ev, mine in zip(ref_stats[key], ours, strict=True):
            for stat in ("rmse", "mean", "median", "std", "min", "max", "sse"):
                assert getattr(mine, stat) == pytest.approx(ev[stat], rel=1e-6, abs=1e-9), (
                    key,
                    stat,
                )
