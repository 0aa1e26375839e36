"""The dataset factory (``io.datasets.open_dataset``) and its readers: each path kind gets its reader,
written scans read back exactly, times and point offsets as given, one IMU shape, bad paths named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imuslam.errors import InputError
from imuslam.interfaces import ImuLog, LidarSource, StereoSource
from imuslam.io.datasets import open_dataset
from imuslam.io.lidarsets import KittiFolder, PcdFolder, azimuth_times
from imuslam.io.pointcloud import write_pcd
from imuslam.io.stereosets import EurocStereo


def _scans(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    return [rng.uniform(-20.0, 20.0, size=(50 + 7 * k, 3)).astype(np.float32) for k in range(n)]


def test_pcd_folder_reads_back_its_scans_in_natural_order(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    scans = _scans(rng, 11)
    for k, pts in enumerate(scans):  # scan10 after scan9: natural, not lexical, order
        write_pcd(tmp_path / f"scan{k}.pcd", pts, intensity=np.full(len(pts), float(k)))
    t_s = 100.0 + 0.1 * np.arange(11) + rng.uniform(0, 0.01, 11)
    np.savetxt(tmp_path / "times.txt", t_s, fmt="%.9f")
    ds = PcdFolder(tmp_path, times=tmp_path / "times.txt")
    assert isinstance(open_dataset(tmp_path, "lidar"), PcdFolder)
    assert isinstance(ds, LidarSource) and ds.imu() is None and len(ds) == 11
    got = list(ds.lidar_scans())
    for k, (s, pts) in enumerate(zip(got, scans, strict=True)):
        assert np.array_equal(s.points_l, pts)  # float32 written, float32 read: bit for bit
        assert np.all(s.intensity == k)
        assert s.t_ns == round(t_s[k] * 1e9)
        assert not np.any(s.t_offset_s)  # a registered scan: every point at its stamp


def test_pcd_points_are_timed_from_their_azimuth_when_deskewed(tmp_path: Path) -> None:
    az = np.deg2rad(np.array([-179.0, -90.0, 0.0, 90.0, 179.0]))
    pts = np.column_stack([np.cos(az), np.sin(az), np.zeros(5)]) * 10.0
    write_pcd(tmp_path / "0.pcd", pts)
    s = next(PcdFolder(tmp_path, rate_hz=10.0, deskew=True).lidar_scans())
    # a counter-clockwise sweep from -x over 0.1 s: -179 deg at 1/360 of it, +90 deg at 3/4
    want = (az + np.pi) / (2 * np.pi) * 0.1
    assert np.allclose(s.t_offset_s, want, atol=1e-7)
    assert np.allclose(azimuth_times(pts, 0.1), want, atol=1e-7)


def test_kitti_folder_reads_points_reflectance_and_times(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    (tmp_path / "velodyne").mkdir()
    scans = _scans(rng, 3)
    refl = [rng.uniform(0, 1, len(p)).astype(np.float32) for p in scans]
    for k, (p, r) in enumerate(zip(scans, refl, strict=True)):
        np.column_stack([p, r]).astype("<f4").tofile(tmp_path / "velodyne" / f"{k:06d}.bin")
    (tmp_path / "times.txt").write_text("0.000000e+00\n1.037359e-01\n2.073880e-01\n")
    ds = open_dataset(tmp_path, "lidar")
    assert isinstance(ds, KittiFolder) and ds.imu() is None
    got = list(ds.lidar_scans())
    assert [s.t_ns for s in got] == [0, 103_735_900, 207_388_000]
    for s, p, r in zip(got, scans, refl, strict=True):
        assert np.array_equal(s.points_l, p) and np.array_equal(s.intensity, r)


def test_scan_times_that_go_back_name_the_line(tmp_path: Path) -> None:
    for k in range(3):
        write_pcd(tmp_path / f"{k}.pcd", np.ones((4, 3)))
    (tmp_path / "t.txt").write_text("0.0\n0.2\n0.1\n")
    with pytest.raises(InputError, match=r"t.txt: line 3: scan times go back"):
        PcdFolder(tmp_path, times=tmp_path / "t.txt")


@pytest.mark.parametrize(
    ("sensor", "name", "message"),
    [
        ("lidar", "nothing_here", "no such bag or folder"),
        ("stereo", "nothing_here", r"not an EuRoC folder \(no mav0/cam0\)"),
        ("stereo", "run.bag", "a bag needs --camchain, --left-topic and --right-topic"),
        ("lidar", "empty.bag", "cannot open as a ROS bag"),
    ],
)
def test_bad_paths_are_one_line_errors(
    sensor: str, name: str, message: str, tmp_path: Path
) -> None:
    (tmp_path / "empty.bag").write_bytes(b"")
    with pytest.raises(InputError, match=message) as e:
        open_dataset(tmp_path / name, sensor)  # type: ignore[call-overload]
    assert str(tmp_path / name) in str(e.value) and "\n" not in str(e.value)


def test_euroc_folder_is_a_stereo_source_with_its_imu(shared_data: Path) -> None:
    root = shared_data / "euroc_V1_01_micro_kimera"
    ds = open_dataset(root, "stereo")
    assert isinstance(ds, EurocStereo) and isinstance(ds, StereoSource)
    imu = ds.imu()
    rows = [ln for ln in (root / "mav0/imu0/data.csv").read_text().splitlines() if ln[:1].isdigit()]
    assert isinstance(imu, ImuLog) and len(imu) == len(rows)
    assert imu.t_ns[0] == int(rows[0].split(",")[0])
    # the excerpt lists pairs whose images it left out: counted, not given
    skipped = ds.skipped_frames()
    assert skipped["unreadable"] == 0 and ds.counts.listed == len(ds) + skipped["missing"]
    assert len(ds) == len(ds.t_ns) > 0


def test_the_loaders_map_the_one_path_kind(tmp_path: Path) -> None:
    """The IMU and the 2D laser loaders take a bag, a EuRoC folder and a simulation folder from
    ``source_kind``, a file's format from its name or content, and name the folder they cannot read."""
    from imuslam.io import laserload, load

    bag, euroc, sim, other = (tmp_path / n for n in ("ros2", "euroc", "sim", "other"))
    for d in (bag, euroc / "mav0", sim, other):
        d.mkdir(parents=True)
    (bag / "metadata.yaml").write_text("{}\n")
    (sim / "sim.npz").write_bytes(b"")
    assert [load.detect_format(p) for p in (bag, euroc, tmp_path / "x.mcap")] == [
        "bag",
        "euroc",
        "bag",
    ]
    assert [laserload.detect_format(p) for p in (bag, sim, tmp_path / "x.bag")] == [
        "bag",
        "sim",
        "bag",
    ]
    names = ("a.dat", "b.clf", "c.log.bz2", "d.gz", "e.npz")
    assert [laserload.detect_format(tmp_path / n) for n in names] == [
        "breezyslam", "carmen", "carmen", "carmen", "sim"
    ]  # fmt: skip
    (tmp_path / "imu.txt").write_text("0 0 0 9.8 0 0 0\n")
    assert load.detect_format(tmp_path / "imu.txt") == "imutk"
    for p in (sim, other):
        with pytest.raises(InputError) as e:
            load.detect_format(p)
        assert str(e.value) == f"{p}: a folder that is neither a ROS 2 bag nor a EuRoC dataset"
    for p in (euroc, other):
        with pytest.raises(InputError) as e:
            laserload.detect_format(p)
        assert (
            str(e.value)
            == f"{p}: a folder without sim.npz (expected the output of imuslam simulate)"
        )
    with pytest.raises(InputError, match=r"x\.txt: unknown log kind; expected a CARMEN log"):
        laserload.detect_format(tmp_path / "x.txt")
