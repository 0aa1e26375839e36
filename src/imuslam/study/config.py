"""The study file: what to simulate, how to degrade and correct the IMU, which estimators to run, which
claims to test, over which seeds (YAML keys equal the field names; an unknown key is an error naming it).

A study is a list of claims. Each claim expands into cells, the product of its scenarios x IMU conditions
x alignment methods x estimator variants x the study's seeds; its report compares the levels of one
factor (``compare``) in the order the claim states (``expect``, best first), paired by seed.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from imuslam.errors import InputError

ImuCondition = Literal["ideal", "raw", "offline", "online", "drifting"]
IMU_CONDITIONS = ("ideal", "raw", "offline", "online", "drifting")
# kf_attitude: the Kalman alignment's attitude only; its bias estimates are not applied, so the run's
# IMU errors are what the calibration left (the cell then measures the calibration, not the alignment)
AlignName = Literal["none", "kf", "stkf", "rwnn", "kf_attitude"]
ALIGN_NAMES = ("none", "kf", "stkf", "rwnn", "kf_attitude")
# navigation scenes of the simulator (sim/scenario.py); 'gimbal' is a calibration log, not a drive
NAV_SCENARIOS = ("room", "square", "street", "corridor", "handheld")
Factor = Literal["scenario", "imu", "alignment", "estimator"]
#: A seed every generator of a cell accepts (numpy's legacy RandomState and numba's take 32 bits).
Seed = Annotated[int, Field(ge=0, le=2**32 - 1)]


#: The most seeds a count may ask for (each seed is a run of every cell of a claim).
MAX_SEED_COUNT = 10_000


def _seed_list(v: Any) -> Any:
    """``seeds: N`` is the seeds 0 .. N-1; a list is kept for the field's own checks."""
    if isinstance(v, int) and not isinstance(v, bool):
        if v > MAX_SEED_COUNT:
            raise ValueError(
                f"a count of {v} seeds; expected at most {MAX_SEED_COUNT} (or a list of seeds)"
            )
        return list(range(v))
    return v


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class ScenarioSpec(_Strict):
    """A simulated scene and how long the estimator runs on it (after the alignment window)."""

    name: str
    duration_s: float = Field(30.0, gt=0, le=3600, description="estimation run, s")

    @field_validator("name")
    @classmethod
    def _known(cls, v: str) -> str:
        if v == "gimbal":
            raise ValueError(
                "'gimbal' is the calibration log, not a navigation scene; expected one of "
                + ", ".join(NAV_SCENARIOS)
            )
        if v not in NAV_SCENARIOS:
            raise ValueError(f"unknown scenario '{v}'; expected one of {', '.join(NAV_SCENARIOS)}")
        return v


class EstimatorSpec(_Strict):
    """One estimator variant: the estimator's name, a label for the report, and its options (checked
    against the estimator's own options model when the study is loaded)."""

    name: str
    label: str | None = None
    options: dict[str, Any] = Field(default_factory=dict)

    @property
    def variant(self) -> str:
        return self.label or self.name

    @field_validator("options")
    @classmethod
    def _finite(cls, v: dict[str, Any]) -> dict[str, Any]:
        def walk(x: Any, where: str) -> None:
            if isinstance(x, float) and not math.isfinite(x):
                raise ValueError(f"{where}: {x}; expected a finite number")
            if isinstance(x, dict):
                for key, val in x.items():
                    walk(val, f"{where}.{key}" if where else str(key))
            elif isinstance(x, list):
                for j, val in enumerate(x):
                    walk(val, f"{where}[{j}]")

        walk(v, "")
        return v


class DriftSpec(_Strict):
    """How the IMU's errors move with working time (seed 000: time and temperature), from seed 000's
    table-2 errors. ``age_h``: hours between the offline calibration and the run."""

    age_h: float = Field(4.0, ge=0, le=8760, description="at most a year")
    accel_bias_per_h: tuple[float, float, float] = (0.01, -0.008, 0.012)  # m/s^2 per hour, raw
    gyro_bias_per_h_dps: tuple[float, float, float] = (0.05, -0.04, 0.03)  # deg/s per hour, raw
    scale_per_h: float = Field(5e-4, description="relative change of every scale factor per hour")


class AlignSpec(_Strict):
    """The alignment window before the run: position fixes (RTK / motion capture), and the initial
    attitude error a coarse levelling and a rough heading leave (1-sigma roll, pitch, yaw)."""

    duration_s: float = Field(60.0, gt=0, le=3600)
    fix_rate_hz: float = Field(10.0, gt=0, le=1000)
    fix_std_m: float = Field(0.02, gt=0, le=100)
    init_attitude_err_deg: tuple[
        Annotated[float, Field(ge=0, le=180)],
        Annotated[float, Field(ge=0, le=180)],
        Annotated[float, Field(ge=0, le=180)],
    ] = (0.5, 0.5, 2.0)


class ClaimSpec(_Strict):
    """One claim and the cells that test it."""

    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$")
    seed_doc: str = Field("", description="the seed document that makes the claim, e.g. '001'")
    statement: str = ""
    scenarios: list[ScenarioSpec] = Field(min_length=1)
    imu: list[ImuCondition] = Field(default_factory=lambda: ["online"], min_length=1)  # type: ignore[arg-type]
    alignment: list[AlignName] = Field(default_factory=lambda: ["none"], min_length=1)  # type: ignore[arg-type]
    estimators: list[EstimatorSpec] = Field(min_length=1)
    compare: Factor
    expect: list[str] = Field(
        default_factory=list, description="levels of `compare`, best first (the claimed order)"
    )
    metric: str = "ape_rmse_m"
    lower_is_better: bool = True
    seeds: list[Seed] | None = Field(
        None,
        min_length=1,
        description="this claim's seeds (a count or a list); default: the study's",
    )
    align: AlignSpec | None = Field(
        None, description="this claim's alignment window; default: the study's"
    )
    eval_align: Literal["se3", "sim3", "yaw", "first", "none"] = "se3"
    # enough evidence, decided before the run (study/sequential.py): required when levels are compared
    practical_bound: float | None = Field(
        None,
        gt=0,
        description="the smallest difference of the metric that matters in practice, metric units",
    )
    reason: str = Field("", description="why that bound: one line")
    max_seeds: int | None = Field(
        None, ge=2, le=MAX_SEED_COUNT, description="seed budget: seeds are added up to this many"
    )
    seed_batch: int | None = Field(
        None, ge=1, description="seeds added per look; default: as many as the first seeds"
    )

    @field_validator("seeds", mode="before")
    @classmethod
    def _seed_count(cls, v: Any) -> Any:
        return _seed_list(v)

    def levels(self) -> list[str]:
        if self.compare == "scenario":
            return [s.name for s in self.scenarios]
        if self.compare == "imu":
            return [str(x) for x in self.imu]
        if self.compare == "alignment":
            return [str(x) for x in self.alignment]
        return [e.variant for e in self.estimators]

    @model_validator(mode="after")
    def _expect_levels(self) -> ClaimSpec:
        lv = self.levels()
        if len(set(lv)) != len(lv):
            raise ValueError(f"claim '{self.name}': the levels of '{self.compare}' repeat: {lv}")
        for e in self.expect:
            if e not in lv:
                raise ValueError(
                    f"claim '{self.name}': expect names '{e}', which is not a level of "
                    f"'{self.compare}' ({', '.join(lv)})"
                )
        labels = [e.variant for e in self.estimators]
        if len(set(labels)) != len(labels):
            raise ValueError(
                f"claim '{self.name}': two estimator entries share the label {labels}; give each a label"
            )
        if len(lv) >= 2:
            missing = [k for k in ("practical_bound", "max_seeds") if getattr(self, k) is None]
            if missing:
                raise ValueError(
                    f"claim '{self.name}' compares {len(lv)} levels of '{self.compare}' but states no "
                    f"{' and no '.join(missing)}; expected the smallest difference of {self.metric} "
                    "that matters (practical_bound, with its reason) and a seed budget (max_seeds)"
                )
            if not self.reason.strip():
                raise ValueError(
                    f"claim '{self.name}': practical_bound {self.practical_bound:g} has no reason; "
                    "expected one line saying why that difference matters"
                )
        if (
            self.max_seeds is not None
            and self.seeds is not None
            and len(self.seeds) > self.max_seeds
        ):
            raise ValueError(
                f"claim '{self.name}': {len(self.seeds)} seeds but max_seeds {self.max_seeds}; "
                "expected at most max_seeds"
            )
        return self

    def first_seeds(self, study_seeds: list[int]) -> list[int]:
        """The seeds of the first look: the claim's, else the study's (at most ``max_seeds``)."""
        first = list(dict.fromkeys(self.seeds or study_seeds))
        return first[: self.max_seeds] if self.max_seeds is not None else first

    def batch(self, study_seeds: list[int]) -> int:
        """Seeds added per look (``seed_batch``, default as many as the first look has)."""
        return self.seed_batch or max(1, len(self.first_seeds(study_seeds)))


class StudyConfig(_Strict):
    """A whole study (see the module docstring)."""

    name: str = "study"
    seeds: list[Seed] = Field(default_factory=lambda: [0, 1, 2], min_length=1)
    drift: DriftSpec = Field(default_factory=DriftSpec)
    align: AlignSpec = Field(default_factory=AlignSpec)
    claims: list[ClaimSpec] = Field(min_length=1)

    @field_validator("seeds", mode="before")
    @classmethod
    def _seed_count(cls, v: Any) -> Any:
        return _seed_list(v)

    @field_validator("claims")
    @classmethod
    def _unique(cls, v: list[ClaimSpec]) -> list[ClaimSpec]:
        names = [c.name for c in v]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"claim names repeat: {', '.join(sorted(dup))}")
        return v


def _where(loc: tuple[Any, ...], data: Any) -> str:
    """'claims[1].estimators[0].name' with the claim's name where there is one."""
    parts: list[str] = []
    node = data
    for p in loc:
        if isinstance(p, int):
            name = (
                node[p].get("name")
                if isinstance(node, list) and isinstance(node[p], dict)
                else None
            )
            parts[-1] += f"[{p}]" + (
                f" ({name})" if name and parts[-1] in ("claims", "logs", "runs") else ""
            )
        else:
            parts.append(str(p))
        try:
            node = node[p]
        except (KeyError, IndexError, TypeError):
            node = None
    return ".".join(parts)


def parse_study(data: Any, source: str = "<study>") -> StudyConfig:
    """Validate a study dict; the first problem becomes one InputError line naming the field."""
    if not isinstance(data, dict):
        raise InputError(f"{source}: a study is a mapping with 'claims' (and seeds, drift, align)")
    try:
        return StudyConfig.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        empty = (
            "a study needs at least one seed"
            if err["loc"][-1] == "seeds"
            else "the study has no cells"
        )
        raise InputError(f"{source}: {validation_line(exc, data, empty)}") from None


def validation_line(exc: ValidationError, data: Any, empty: str) -> str:
    """The first error of ``exc`` as '<where in data>: <what>'; ``empty`` says what an empty list means."""
    err = exc.errors()[0]
    where = _where(tuple(err["loc"]), data)
    if err["type"] == "extra_forbidden":
        return f"{where}: unknown key"
    if err["type"] == "too_short":
        return f"{where} is empty: {empty}"
    return f"{where}: " + err["msg"].removeprefix("Value error, ")


def read_study_data(path: str | Path) -> Any:
    """The mapping of a study YAML, not yet validated (a study over the simulator has 'claims', a
    study of recorded logs 'logs': ``study.logconfig``)."""
    from imuslam.io.yamlfile import read_yaml

    return read_yaml(
        path, "a study: a mapping with 'claims' (and seeds, drift, align), or with 'logs'"
    )


def load_study(path: str | Path) -> StudyConfig:
    """Read and validate a study YAML."""
    return parse_study(read_study_data(path), str(path))


def dump_study(study: StudyConfig) -> str:
    """The effective study as YAML (every default written out)."""
    return yaml.safe_dump(study.model_dump(mode="json"), sort_keys=False)
