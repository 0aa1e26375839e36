"""Configuration of the LiDAR(-inertial) odometry: nested pydantic models, YAML keys = field names."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

if TYPE_CHECKING:
    from imuslam.lio.matcher import MatchParams

FloatArray = NDArray[np.float64]


class ExtrinsicConfig(BaseModel):
    """The LiDAR pose in the IMU frame ``T_i_l`` (translation m, rotation as a Hamilton quaternion) and
    the LiDAR clock offset: ``t_imu = t_lidar + time_offset_s`` (within a second: a larger offset is a
    clock in another epoch or unit, not a latency)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    p_i_l: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat_wxyz_i_l: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    time_offset_s: float = Field(0.0, ge=-1.0, le=1.0)

    @field_validator("quat_wxyz_i_l")
    @classmethod
    def _unit(cls, q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        n = float(np.linalg.norm(q))
        if not abs(n - 1.0) < 1e-3:
            raise ValueError(f"quat_wxyz_i_l must be a unit quaternion, its norm is {n:.6f}")
        return q

    def T_i_l(self) -> FloatArray:
        from imuslam.geometry import quat_to_matrix

        T = np.eye(4)
        T[:3, :3] = quat_to_matrix(np.asarray(self.quat_wxyz_i_l, dtype=float))
        T[:3, 3] = self.p_i_l
        return T


@dataclass
class ObservabilityLimits:
    """The largest 1-sigma at which a parameter still counts as observed: rotation about an IMU axis,
    deg; lever arm along an IMU axis, m; clock offset, s (``lio.extrinsic``'s verdict and the
    filter's guard, ``lio.online_calib``)."""

    rotation_deg: float = 0.5
    translation_m: float = 0.03
    time_offset_s: float = 0.005


class FrontEndConfig(BaseModel):
    """mode: LOAM features or voxel-downsampled raw points; scan_voxel: downsampling of the scan, m;
    min_range / max_range: points kept, m (a voxel under 1 cm or a range beyond 10 km is a value in
    another unit)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    mode: Literal["features", "direct"] = "features"
    scan_voxel: float = Field(1.0, ge=0.01, le=100.0)
    min_range: float = Field(1.0, ge=0)
    max_range: float = Field(100.0, gt=0, le=1e4)
    edge_threshold: float = Field(0.005, gt=0)
    plane_threshold: float = Field(0.003, gt=0)

    @model_validator(mode="after")
    def _ranges(self) -> FrontEndConfig:
        if not self.min_range < self.max_range:
            raise ValueError(
                f"frontend.min_range {self.min_range:g} m must be below frontend.max_range "
                f"{self.max_range:g} m (no point would be kept)"
            )
        return self


class MapConfig(BaseModel):
    """voxel: map voxel size, m; max_per_voxel: points per voxel; radius: local map radius, m;
    knn: the k-nearest-neighbour search: ``ivox`` (the incremental voxel-hash map searched over the
    27 cells around a query, ``lio.ivox``, never rebuilt) or a k-d tree library rebuilt after each insertion;
    max_residual: the association gate, m: a scan point farther than this from its neighbours' plane
    (line) is not matched. It equals the plane test's thickness (``MatchParams.max_plane_res``, 0.1 m,
    FAST-LIO2's): a point farther from the plane than the plane's own points may lie is on another
    surface (a wall's foot matched to the ground, a pole to the wall behind it). A wider gate (it was
    1 m) lets those wrong matches in at full Huber weight and they tilt every scan by a few hundredths
    of a degree, which the map built from those poses accumulates (0.4-0.6 deg of roll / pitch over
    50 m on the simulated street, README: LIO covariance)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    voxel: float = Field(0.5, ge=0.01, le=100.0)
    max_per_voxel: int = Field(1, ge=1, le=100)
    radius: float = Field(100.0, gt=0, le=1e4)
    knn: Literal["ivox", "pykdtree", "small_gicp", "scipy"] = "ivox"
    max_residual: float = Field(0.1, gt=0)

    def match_params(self) -> MatchParams:
        """The association's gates (``lio.matcher.MatchParams``) with this ``max_residual``."""
        from imuslam.lio.matcher import MatchParams

        return MatchParams(max_residual=self.max_residual)


# the map's drift per front end: (attitude deg, position m) per sqrt(m) of path (FilterConfig). Zero:
# the rates once fitted on simulated seeds (direct 0.123 deg / 0.017 m, features 0.08 / 0.011) stood
# for the roll / pitch drift of the 1 m association gate (MapConfig.max_residual); with the gate at
# the plane test's 0.1 m the reported covariance is conservative without them (README, LIO covariance)
MAP_DRIFT = {"features": (0.0, 0.0), "direct": (0.0, 0.0)}


class FilterConfig(BaseModel):
    """state: reduced [p, v, theta, g] (12) for a corrected IMU or full with biases (18); noise densities
    of the IMU (continuous, per sqrt(Hz)) and bias random walks; lidar_std: point-to-plane 1-sigma, m;
    lidar_dof: independent residuals a scan is worth (map and plane-fit errors are shared by many points,
    so thousands of residuals do not carry thousands of independent errors; R is scaled by M / lidar_dof
    when a scan has M > lidar_dof residuals; it does not make the absolute covariance consistent,
    see map_covariance); lidar_model: ``dof`` (default) that diagonal R; ``plane`` each row's own
    range noise projected on its normal plus the error of the plane (line) fitted to its k frozen map
    points, shared by the rows that fit the same points, whitened into an equivalent 6-row update,
    with Tukey weights on the residuals in units of their sigma (``lio.rowcov``; no lidar_dof); it
    gives one scan's covariance right but the filter with it is overconfident (README, LIO
    covariance) and about 10x slower a scan; ``plane_diag`` the same rows' noise with the map
    points' part kept on each row's own variance only (no sharing, no sparse factorisation): about
    as accurate as ``plane`` at about 1.3x the default's CPU a scan, as overconfident;
    lidar_range_std: the LiDAR's range noise 1-sigma for the ``plane`` models, m (datasheet; the
    simulated VLP-16's is 0.02); start_covariance (the ``plane`` models only): the start map's
    record (``MapCovariance``, the points from before the filter) carries the LiDAR-only start's
    covariance, its registrations' covariances with the rows' model chained along the start, instead
    of zero (every later pose inherits the start's error: without it the NEES is 5-24x higher; with it
    still 12-55x above the band, docs/measurements/lio.md);
    max_iterations and the convergence threshold of the iterated update (on |dx|); reassociate: an
    iterate searches the map's neighbours again only when it moved a point 20 m away by more than this
    since the last search, m (0: at every iterate, as FAST-LIO2); map_covariance (default on): the
    reported covariance is the absolute one, the filter's map-relative covariance plus the matched
    map's (every map point remembers the scan that inserted it, whose absolute pose covariance is
    recorded; a consider term that never enters the gain, so the estimate is the same either way,
    ``estimator.MapCovariance``); off: the filter's own covariance, of the pose relative to the map
    taken as exact (FAST-LIO2's), overconfident for the absolute pose; map_correlation: how the
    matched map pieces' errors combine (``estimator.MapCovariance``): ``full`` (default) fully
    correlated, never found overconfident; ``independent``: each piece's own map-relative part
    independent of the others' (closer on short drives, overconfident on some 20 s drives);
    map_drift_deg_per_sqrt_m /
    map_drift_m_per_sqrt_m: the map's error as a random walk along the path, per axis (attitude deg
    and position m per sqrt(m) of path; each map record gains that variance times the path since the
    previous one), in the world of the first IMU pose where the map has no error; ``None`` takes
    the front end's default (``MAP_DRIFT``, filled in by ``LioConfig.resolved``: zero, the matched
    map's recorded covariance alone; a user whose scenes drift sets the rates from the RPE of their
    own runs); max_speed / max_rate bound a physically possible state
    (divergence check). imu_guard (default on): gyro samples at the range (``gyro_range_dps``, the
    datasheet's, or detected from the log when unset; within ``gyro_clip_margin`` of it) are bridged
    and their error and the IMU gaps' enter the covariance (``lio.guards``); degeneracy_guard
    (default on): a direction of the pose whose 1-sigma from a scan alone exceeds ``degenerate_std``
    (m; rotation as metres at 10 m) is kept at the IMU's prediction (Zhang 2016's solution remapping);
    the degenerate scans are reported either way; min_match_fraction / lost_scans: fewer of a scan's
    points matched to the map than this fraction for that many scans in a row is a divergence the
    filter reports (exit 3) instead of going on with a map it lost (0 turns the check off);
    estimate_extrinsic / estimate_time_offset (off by default): the LiDAR's rotation and translation
    on the IMU (6 states) and the LiDAR-to-IMU clock offset (1 state) refined inside the filter
    (``lio.online_calib``), from the ``extrinsic`` section as prior with the 1-sigma
    extrinsic_rot_std_deg (about each IMU axis, deg), extrinsic_p_std (m) and time_offset_std (s), and
    a random walk per sqrt(s) (extrinsic_rot_rw_deg, extrinsic_p_rw, time_offset_rw);
    extrinsic_guard (default on): a direction of those states whose 1-sigma from the scans alone is
    still above the prior's is held at its prior instead of following the filter's noise; the run
    reports the directions whose 1-sigma from the scans exceeds ``ObservabilityLimits`` unobserved."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    state: Literal["reduced", "full"] = "full"
    accel_noise: float = Field(0.02, gt=0)
    gyro_noise: float = Field(2e-3, gt=0)
    accel_bias_rw: float = Field(1e-3, ge=0)
    gyro_bias_rw: float = Field(1e-4, ge=0)
    lidar_std: float = Field(0.05, gt=0)
    lidar_dof: float = Field(30.0, gt=0)
    lidar_model: Literal["dof", "plane", "plane_diag"] = "dof"
    lidar_range_std: float = Field(0.02, gt=0)
    max_iterations: int = Field(5, ge=1, le=100)
    reassociate: float = Field(0.02, ge=0)
    converge: float = Field(1e-3, gt=0)
    map_covariance: bool = True
    map_correlation: Literal["full", "independent"] = "full"
    start_covariance: bool = False
    map_drift_deg_per_sqrt_m: float | None = Field(None, ge=0)
    map_drift_m_per_sqrt_m: float | None = Field(None, ge=0)
    max_speed: float = Field(60.0, gt=0)
    imu_guard: bool = True
    gyro_range_dps: float | None = Field(None, gt=0, le=1e4)
    gyro_clip_margin: float = Field(0.03, ge=0, lt=0.5)
    degeneracy_guard: bool = True
    degenerate_std: float = Field(0.1, gt=0)
    min_match_fraction: float = Field(0.15, ge=0, lt=1)
    lost_scans: int = Field(3, ge=1)
    estimate_extrinsic: bool = False
    estimate_time_offset: bool = False
    extrinsic_rot_std_deg: float = Field(3.0, gt=0, le=30.0)
    extrinsic_p_std: float = Field(0.15, gt=0, le=2.0)
    time_offset_std: float = Field(0.03, gt=0, le=0.5)
    extrinsic_rot_rw_deg: float = Field(0.05, ge=0)
    extrinsic_p_rw: float = Field(1e-3, ge=0)
    time_offset_rw: float = Field(1e-4, ge=0)
    extrinsic_guard: bool = True
    g: float = Field(9.80665, ge=9.7, le=9.9, description="gravity on earth, m/s^2")

    @model_validator(mode="after")
    def _start_needs_rows_model(self) -> FilterConfig:
        if self.start_covariance and self.lidar_model == "dof":
            raise ValueError(
                "filter.start_covariance needs filter.lidar_model plane or plane_diag (the start's "
                "registration covariance comes from the rows' model)"
            )
        if (self.estimate_extrinsic or self.estimate_time_offset) and self.lidar_model != "dof":
            raise ValueError(
                "filter.estimate_extrinsic and filter.estimate_time_offset need filter.lidar_model "
                "dof (the point-to-plane rows; the plane models whiten them into 6 rows)"
            )
        return self


class LioConfig(BaseModel):
    """Everything the LiDAR-inertial odometry needs beside its input."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    extrinsic: ExtrinsicConfig = ExtrinsicConfig()
    frontend: FrontEndConfig = FrontEndConfig()
    map: MapConfig = MapConfig()
    filter: FilterConfig = FilterConfig()
    align: Literal["none", "kf", "stkf", "rwnn"] = "none"
    align_seconds: float = Field(1.0, gt=0, le=3600)
    use_imu: bool = True

    def resolved(self) -> LioConfig:
        """A copy with ``filter.map_drift_*`` left empty filled with the front end's default
        (``MAP_DRIFT``): what the estimator uses and what is written beside the results (resolved
        at use, so a front end changed after construction takes its own rates)."""
        q_deg, q_m = MAP_DRIFT[self.frontend.mode]
        f = self.filter
        drift = {"map_drift_deg_per_sqrt_m": q_deg if f.map_drift_deg_per_sqrt_m is None else f.map_drift_deg_per_sqrt_m,
                 "map_drift_m_per_sqrt_m": q_m if f.map_drift_m_per_sqrt_m is None else f.map_drift_m_per_sqrt_m}  # fmt: skip
        return self.model_copy(update={"filter": f.model_copy(update=drift)})
