"""The estimators a study can run: a registry of name -> adapter.

An adapter is one function ``run(inp: CellInput) -> Estimate``: it gets the cell's simulated scene, the
IMU as the cell's condition and alignment left it, and the state at the start of the run, drives the
estimator's library API (never the CLI), and returns the estimated body poses in the world frame; the
study evaluates them against the truth the same way for every estimator. An adapter simulates the other
sensors its estimator needs (LiDAR, stereo, wheels) from ``inp.sensor_rng(name)``, so every level of a
claim sees the same sensor noise.

Register an adapter with :func:`register` (its options as a strict pydantic model, checked when the
study is loaded; the scenarios that carry its sensors).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from imuslam.errors import InputError
from imuslam.ins.strapdown import integrate
from imuslam.interfaces import ImuLog, NavState, Trajectory
from imuslam.sim.imu import ImuTruth
from imuslam.sim.trajectory import EulerTrajectory
from imuslam.sim.world import World
from imuslam.study.cells import Cell, digest
from imuslam.study.config import NAV_SCENARIOS, StudyConfig

FloatArray = NDArray[np.float64]


@dataclass
class CellInput:
    """What an adapter gets.

    imu: the IMU log of the run, from ``t_start_s`` to the end (SI units, body frame; corrected by the
        cell's IMU condition and with the alignment's bias estimates removed); ``imu_truth`` the truth at
        every sample of the whole simulated span (alignment window included), ``k_start`` the run's
        first sample in it.
    init: the navigation state at ``t_start_s`` (position and velocity true, attitude from the alignment).
    traj / world: the simulated trajectory (``traj.state(t_s)``) and scene, for simulating other sensors.
    rng: the estimator's own generator (seeded from the cell hash).
    """

    cell: Cell
    options: BaseModel
    traj: EulerTrajectory
    world: World
    imu: ImuLog
    imu_truth: ImuTruth
    k_start: int
    t_start_s: float
    t_end_s: float
    init: NavState
    g: float
    rng: np.random.Generator
    shared: Any = None

    def sensor_rng(self, sensor: str) -> np.random.Generator:
        """The scene's generator for ``sensor`` (the same for every level of a claim)."""
        return self.cell.world_rng(sensor)


@dataclass
class Estimate:
    """Estimated body poses in the world frame, and metrics of the estimator's own (map quality...)."""

    traj: Trajectory
    metrics: dict[str, float] = field(default_factory=dict)


class NoOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")


Prepare = Callable[[Cell], tuple[str, Callable[..., Any], tuple[Any, ...]] | None]


@dataclass(frozen=True)
class EstimatorEntry:
    """An estimator: its adapter ``run``, options model, the scenes it runs on, and optionally
    ``prepare(cell) -> (key, fn, args)``: work several cells share (e.g. a VO front end over the same
    images for every filter variant), run once per key as a task of its own; ``fn(*args)`` arrives in
    ``CellInput.shared``. ``missing`` says why an estimator without ``run`` is not available.
    ``own_alignment``: the estimator aligns itself (the cell's alignment method is its option, read from
    ``inp.cell.alignment``); the study's fix-aided alignment window is then not run. ``cpu_per_s``: CPU
    seconds a cell takes per second of run (measured on the simulator, shared work included), so the
    runner can start the longest cells first."""

    name: str
    doc: str
    options: type[BaseModel]
    scenarios: tuple[str, ...]
    run: Callable[[CellInput], Estimate] | None
    missing: str = ""
    prepare: Prepare | None = None
    own_alignment: bool = False
    cpu_per_s: float = 0.01


REGISTRY: dict[str, EstimatorEntry] = {}


def register(
    name: str,
    options: type[BaseModel],
    scenarios: tuple[str, ...],
    doc: str,
    prepare: Prepare | None = None,
    own_alignment: bool = False,
    cpu_per_s: float = 0.01,
) -> Callable[[Callable[[CellInput], Estimate]], Callable[[CellInput], Estimate]]:
    """Decorator: make ``run`` the adapter of estimator ``name``."""

    def deco(run: Callable[[CellInput], Estimate]) -> Callable[[CellInput], Estimate]:
        REGISTRY[name] = EstimatorEntry(name, doc, options, scenarios, run, prepare=prepare,
                                        own_alignment=own_alignment, cpu_per_s=cpu_per_s)  # fmt: skip
        return run

    return deco


def get_estimator(name: str) -> EstimatorEntry:
    """The entry of ``name``; ValueError when it is unknown or not available (a study file's names
    are checked by :func:`check_study` first, as InputErrors naming the field)."""
    problem = estimator_problem(name)
    if problem:
        raise ValueError(problem)
    return REGISTRY[name]


def estimator_problem(name: str) -> str:
    """Why ``name`` cannot run (unknown, or its dependency missing), or '' when it can."""
    e = REGISTRY.get(name)
    avail = ", ".join(k for k, v in REGISTRY.items() if v.run is not None)
    if e is None:
        return f"unknown estimator '{name}'; expected one of {', '.join(REGISTRY)} (available: {avail})"
    if e.run is None:
        return f"estimator '{name}' is not available: {e.missing} (available: {avail})"
    return ""


def check_study(study: StudyConfig, source: str = "<study>") -> None:
    """Every estimator exists, runs on the claim's scenarios, and its options are valid."""
    for k, c in enumerate(study.claims):
        for i, est in enumerate(c.estimators):
            where = f"{source}: claims[{k}] ({c.name}).estimators[{i}]"
            problem = estimator_problem(est.name)
            if problem:
                raise InputError(f"{where}: {problem}")
            e = REGISTRY[est.name]
            try:
                e.options.model_validate(est.options)
            except ValidationError as exc:
                err = exc.errors()[0]
                loc = ".".join(str(p) for p in err["loc"])
                msg = "unknown option" if err["type"] == "extra_forbidden" else err["msg"]
                raise InputError(f"{where} ({est.name}).options.{loc}: {msg}") from None
            if e.own_alignment and "kf_attitude" in c.alignment:
                raise InputError(
                    f"{where}: estimator '{est.name}' aligns itself; alignment 'kf_attitude' is for the "
                    "estimators the study aligns"
                )
            for sc in c.scenarios:
                if sc.name not in e.scenarios:
                    raise InputError(
                        f"{where}: estimator '{est.name}' needs a scene with its sensors "
                        f"({', '.join(e.scenarios)}); scenario '{sc.name}' has none"
                    )


# ---------------------------------------------------------------------------------------------
# ins: free inertial navigation from the aligned state


class InsOptions(BaseModel):
    """Free strapdown INS (``ins/strapdown.py``) from the state the alignment left."""

    model_config = ConfigDict(extra="forbid")
    pose_rate_hz: float = Field(
        20.0, gt=0, description="rate of the poses handed to the evaluation"
    )


@register(
    "ins",
    InsOptions,
    NAV_SCENARIOS,
    "free inertial navigation from the aligned state",
    cpu_per_s=0.002,
)
def run_ins(inp: CellInput) -> Estimate:
    opts = inp.options
    assert isinstance(opts, InsOptions)
    log = inp.imu
    t = log.t_s
    P, _, R = integrate(t, log.accel, log.gyro, inp.init, inp.g)
    step = max(1, int(round(log.rate_hz / opts.pose_rate_hz)))
    idx = np.arange(0, len(t), step)
    return Estimate(Trajectory(log.t_ns[idx], P[idx], R[idx], "ins"))


# ---------------------------------------------------------------------------------------------
# vio: stereo VO + EKF with non-holonomic constraints and gating (seed 004), imuslam.vio


class VioOptions(BaseModel):
    """Which track of ``imuslam.vio.pipeline.run_vio`` to score and how the filter runs. The images are
    rendered by the simulator (``sim/render.py``) at ``image_hz``; VO outliers (``outlier_fraction`` of the
    measurements corrupted, the same ones for every variant of a seed) give the gate work to do."""

    model_config = ConfigDict(extra="forbid")
    track: Literal["fused", "vo", "imu"] = "fused"
    nhc: bool = False
    gating: bool = True
    outlier_fraction: float = Field(0.0, ge=0, lt=1)
    image_hz: float = Field(10.0, gt=0, le=60)
    config: dict[str, Any] = Field(
        default_factory=dict, description="further VioConfig fields (imuslam.vio.pipeline)"
    )


def _vio_scene(cell: Cell, image_hz: float) -> Any:
    """The simulator's stereo run over the cell's drive, frames over the estimation window only."""
    from imuslam.sim.stereo_run import SimStereoRun, StereoRunConfig
    from imuslam.study.scenes import scene

    traj, world, _ = scene(cell.scenario.name)
    t0 = cell.align.duration_s
    total = t0 + cell.scenario.duration_s
    data = SimStereoRun(
        StereoRunConfig(
            duration_s=total, image_hz=image_hz, seed=cell.world_seed() % (2**31), t0_ns=0
        ),
        traj,
        world,
    )
    keep = (data.t_frames_ns >= int(round(t0 * 1e9))) & (
        data.t_frames_ns <= int(round(total * 1e9))
    )
    data.t_frames_ns = data.t_frames_ns[keep]
    return data


def _vio_front_end(cell_d: dict[str, Any], image_hz: float, vo_cfg: dict[str, Any]) -> Any:
    """The VO front end over the cell's images (shared by every filter variant of a seed)."""
    from imuslam.vio.frontend import VoConfig
    from imuslam.vio.pipeline import compute_vo

    cell = Cell.model_validate(cell_d)
    return compute_vo(_vio_scene(cell, image_hz), VoConfig.model_validate(vo_cfg))


def _vio_prepare(cell: Cell) -> tuple[str, Callable[..., Any], tuple[Any, ...]]:
    o = VioOptions.model_validate(cell.estimator.options)
    vo_cfg = o.config.get("vo", {})
    # only what decides the images: the scene, the window, the seed (not the IMU, not the filter)
    base = cell.model_copy(update={"imu": "ideal", "alignment": "none", "claim": ""})
    key = "vo-" + digest([base.world_seed(), o.image_hz, vo_cfg])
    return key, _vio_front_end, (base.model_dump(mode="json"), o.image_hz, vo_cfg)


@register(
    "vio",
    VioOptions,
    ("room", "handheld"),
    "stereo VO + EKF (NHC, gating)",
    _vio_prepare,
    cpu_per_s=0.05,
)
def run_vio_cell(inp: CellInput) -> Estimate:
    from imuslam.vio.config import VioConfig
    from imuslam.vio.pipeline import run_vio

    o = inp.options
    assert isinstance(o, VioOptions)
    cfg = VioConfig.model_validate(
        {**o.config, "nhc": o.nhc, "gate_prob": 0.999 if o.gating else None,
         "outlier_fraction": o.outlier_fraction, "outlier_seed": inp.cell.world_seed() % (2**31)}
    )  # fmt: skip
    data = _vio_scene(inp.cell, o.image_hz)
    res = run_vio(data, cfg, vo_run=inp.shared, imu=inp.imu)
    track = {"fused": res.fused, "vo": res.vo, "imu": res.imu}[o.track]
    extra: dict[str, float] = {}
    for kind, st in res.gating.items():
        extra[f"gate_rejected_{kind}"] = float(st.rejected)
    return Estimate(Trajectory(track.t_ns, track.p_w, track.R_w_b, f"vio {o.track}"), extra)


# ---------------------------------------------------------------------------------------------
# map2d: 2D SLAM with 2D LiDAR, wheel odometry and the IMU (seed 000), imuslam.slam2d


class Map2dOptions(BaseModel):
    """``imuslam.slam2d.slam.run_slam2d`` on the simulated robot (``sim/robot2d.py``: RPLIDAR-like scans
    at 10 Hz, wheel encoders) with the cell's IMU; the map scored against the true walls
    (``eval/mapquality.py``)."""

    model_config = ConfigDict(extra="forbid")
    use_imu: bool = True
    use_odometry: bool = True
    loop_closure: bool = True
    score_hits: bool = Field(
        True,
        description="also score the scans' hits, placed with the aligned poses, against the true walls "
        "(map_hit_rms_cm, map_hit_wall_width_cm: no grid, eval.mapquality.hit_sharpness)",
    )
    config: dict[str, Any] = Field(
        default_factory=dict, description="further Slam2dConfig fields (imuslam.slam2d.slam)"
    )


def run_map2d_cell(inp: CellInput) -> Estimate:
    from imuslam.eval.mapquality import map_quality, occupied_centres
    from imuslam.sim.robot2d import planar, simulate_robot2d, with_imu
    from imuslam.slam2d.config import Slam2dConfig
    from imuslam.slam2d.pipeline import render_map, run_slam2d

    o = inp.options
    assert isinstance(o, Map2dOptions)
    cfg = Slam2dConfig.model_validate(
        {**o.config, "use_imu": o.use_imu, "use_odometry": o.use_odometry}
    )
    cfg.loop.enabled = o.loop_closure
    # a cell repeats exactly: the loop search runs inline unless the config asks otherwise (in the
    # background its constraints join the graph whenever the worker thread is done, so two runs differ)
    if "background" not in o.config.get("loop", {}):
        cfg.loop.background = False
    # the robot's scans and wheels over the whole drive (the same for every level of a seed), then the
    # estimation window with the cell's IMU
    sim = simulate_robot2d(
        inp.traj, inp.t_end_s, inp.sensor_rng("robot2d"), world=inp.world, t0_ns=0
    )
    k0 = int(np.searchsorted(sim.log.t_ns, int(round(inp.t_start_s * 1e9))))
    log_ = with_imu(sim.log.slice(k0, len(sim.log)), inp.imu)
    res = run_slam2d(log_, cfg)
    truth = planar(inp.traj, log_.t_ns.astype(np.float64) * 1e-9)

    def occupied(poses_w: FloatArray) -> FloatArray:
        g = render_map(log_, poses_w, cfg)
        return occupied_centres(
            g.prob.astype(np.float64), g.known(), g.x0, g.y0, g.params.resolution
        )

    q = map_quality(res.pose_xy_yaw, truth, occupied, inp.world, sim.scan_height)
    P = res.pose_xy_yaw
    c, s_ = np.cos(P[:, 2]), np.sin(P[:, 2])
    R = np.zeros((len(P), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s_, s_, c, 1.0
    p = np.column_stack([P[:, :2], np.full(len(P), inp.traj.state(np.zeros(1)).p_w[0, 2])])
    extra = {"map_far_pct": 100 * q.frac_far, "map_wall_thickness_cm": 100 * q.wall_thickness_m,
             "loop_error_m": q.loop_error_m, "loop_error_deg": q.loop_error_deg}  # fmt: skip
    if o.score_hits:
        extra.update(_hit_scores(log_, cfg, P, truth, inp.world, sim.scan_height))
    return Estimate(Trajectory(res.t_ns, p, R, "map2d"), extra)


def _hit_scores(log_: Any, cfg: Any, est: FloatArray, truth: FloatArray, world: Any,
                height: float) -> dict[str, float]:  # fmt: skip
    """The scans' hits placed with the estimate aligned to the truth (SE(2)), scored against the walls."""
    from imuslam.eval.mapquality import align_se2, hit_sharpness, transform
    from imuslam.slam2d import pose2
    from imuslam.slam2d.pipeline import scan_points

    al = transform(align_se2(est[:, :2], truth[:, :2]), est)
    pts = scan_points(log_, cfg)
    hits = np.concatenate([pose2.act(al[k], pts[k]) for k in range(len(al)) if len(pts[k])])
    h = hit_sharpness(hits, world, height)
    return {"map_hit_rms_cm": 100 * h.rms_m, "map_hit_wall_width_cm": 100 * h.wall_width_m}


register(
    "map2d",
    Map2dOptions,
    ("room", "corridor", "square"),
    "2D SLAM (scans, wheels, IMU)",
    cpu_per_s=0.16,
)(run_map2d_cell)


# ---------------------------------------------------------------------------------------------
# lio: LiDAR-inertial odometry with its own INS alignment (seed 001), imuslam.lio

LIDAR_P_B_L = {"street": (0.0, 0.0, 0.2), "corridor": (0.0, 0.0, 0.6)}  # the LiDAR above the IMU, m


class LioOptions(BaseModel):
    """``imuslam.lio.pipeline.LioPipeline`` on a simulated VLP-16 (``columns`` per turn at 10 Hz) with
    the cell's IMU. The cell's alignment method is the LIO's own (``LioConfig.align``: over the first
    ``align_seconds`` of the run, aided by the LiDAR-only poses), as in seed 001's system."""

    model_config = ConfigDict(extra="forbid")
    state: Literal["reduced", "full"] = "full"
    use_imu: bool = True
    align_seconds: float = Field(5.0, gt=0)
    columns: int = Field(
        900, ge=90, description="LiDAR columns per turn (1800: a VLP-16 at 0.2 deg)"
    )
    config: dict[str, Any] = Field(
        default_factory=dict, description="further LioConfig fields (imuslam.lio.config)"
    )


def _lio_scans(cell_d: dict[str, Any], columns: int) -> list[Any]:
    """The LiDAR scans over the cell's estimation window (shared by every IMU and alignment level)."""
    from imuslam.sim.lidar import Lidar3dConfig, simulate_lidar3d_scan
    from imuslam.study.scenes import scene

    cell = Cell.model_validate(cell_d)
    traj, world, _ = scene(cell.scenario.name)
    p_b_l = np.asarray(LIDAR_P_B_L[cell.scenario.name])

    def pose_w_l(t: FloatArray) -> tuple[FloatArray, FloatArray]:
        st = traj.state(t)
        return st.R_w_b, st.p_w + st.R_w_b @ p_b_l

    cfg = Lidar3dConfig(columns=columns)
    rng = cell.world_rng("lidar3d")
    t0, t1 = cell.align.duration_s, cell.align.duration_s + cell.scenario.duration_s
    ks = np.arange(int(np.ceil(t0 * cfg.rate_hz - 1e-9)), int(np.floor(t1 * cfg.rate_hz + 1e-9)))
    return [simulate_lidar3d_scan(world, pose_w_l, k / cfg.rate_hz, cfg, rng) for k in ks[:-1]]


def _lio_prepare(cell: Cell) -> tuple[str, Callable[..., Any], tuple[Any, ...]]:
    o = LioOptions.model_validate(cell.estimator.options)
    base = cell.model_copy(update={"imu": "ideal", "alignment": "none", "claim": ""})
    return "lidar-" + digest([base.world_seed(), o.columns]), _lio_scans, (
        base.model_dump(mode="json"), o.columns)  # fmt: skip


@dataclass
class _LidarRun:
    name: str
    scans: list[Any]
    log: ImuLog

    def lidar_scans(self) -> Any:
        return iter(self.scans)

    def imu(self) -> ImuLog:
        return self.log

    def __len__(self) -> int:
        return len(self.scans)


def run_lio_cell(inp: CellInput) -> Estimate:
    from imuslam.lio.config import LioConfig
    from imuslam.lio.pipeline import LioPipeline

    o = inp.options
    assert isinstance(o, LioOptions)
    c = dict(o.config)
    c["extrinsic"] = {**c.get("extrinsic", {}), "p_i_l": LIDAR_P_B_L[inp.cell.scenario.name]}
    c["filter"] = {**c.get("filter", {}), "state": o.state}
    c.update(align=inp.cell.alignment, align_seconds=o.align_seconds, use_imu=o.use_imu)
    cfg = LioConfig.model_validate(c)
    res = LioPipeline(_LidarRun("sim", inp.shared, inp.imu), cfg, imu=inp.imu, progress=False).run()
    tr = res.trajectory
    return Estimate(
        Trajectory(tr.t_ns, tr.p_w, tr.R_w_b, "lio"), {"lio_scans_per_s": res.scans_per_s}
    )


register("lio", LioOptions, ("street", "corridor"), "LiDAR-inertial odometry", _lio_prepare,
         own_alignment=True, cpu_per_s=0.6)(run_lio_cell)  # fmt: skip
