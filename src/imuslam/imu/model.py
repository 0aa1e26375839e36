"""The IMU error model: misalignment T, scale K and bias b of each triad, applied and inverted on arrays.

Tedaldi, Pretto, Menegatti, ICRA 2014, eqs. 1-9 (MISSION.md part A):
``x_O = T K (x_S + b)`` (``bias_sign="plus"``, seed 000's convention) or ``x_O = T K (x_S - b)``
(``"minus"``, imu_tk's ``X' = T K (X - B)``). The body frame is the orthogonalised accelerometer
frame, so the accelerometer's T is upper triangular (3 angles) and the gyro's T is full (6 angles):

    T = [[ 1,     -a_yz,  a_zy],
         [ a_xz,   1,    -a_zx],
         [-a_xy,   a_yx,  1   ]]

Parameter vectors: accelerometer ``[a_yz, a_zy, a_zx, s_x, s_y, s_z, b_x, b_y, b_z]``;
gyroscope ``[g_yz, g_zy, g_zx, g_xz, g_xy, g_yx, s_x, s_y, s_z]`` (its bias is estimated apart), the order
of :func:`misalignment_angles` and of the estimator's parameter vector. Seed 000's eq. 13 lists the gyro
angles as yz, zy, xz, zx, xy, yx; the names here follow the values, so ``g_xz`` is always ``T[1, 0]``.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from imuslam.errors import InputError
from imuslam.interfaces.imu import ImuLog
from imuslam.io.atomic import write_atomic
from imuslam.io.text import read_text
from imuslam.io.yamlfile import read_yaml

FloatArray = NDArray[np.float64]
BiasSign = Literal["plus", "minus"]

ACCEL_PARAM_NAMES = ("a_yz", "a_zy", "a_zx", "s_ax", "s_ay", "s_az", "b_ax", "b_ay", "b_az")
GYRO_PARAM_NAMES = ("g_yz", "g_zy", "g_zx", "g_xz", "g_xy", "g_yx", "s_gx", "s_gy", "s_gz")
GYRO_BIAS_NAMES = ("b_gx", "b_gy", "b_gz")


def misalignment_matrix(
    yz: float, zy: float, zx: float, xz: float = 0.0, xy: float = 0.0, yx: float = 0.0
) -> FloatArray:
    """T from its six angles (Tedaldi 2014, eq. 3); xz = xy = yx = 0 gives the accelerometer's T."""
    return np.array([[1.0, -yz, zy], [xz, 1.0, -zx], [-xy, yx, 1.0]])


def misalignment_angles(T: ArrayLike) -> FloatArray:
    """The six angles ``[yz, zy, zx, xz, xy, yx]`` of a misalignment matrix."""
    M = np.asarray(T, dtype=float)
    return np.array([-M[0, 1], M[0, 2], -M[1, 2], M[1, 0], -M[2, 0], M[2, 1]])


@dataclass
class TriadModel:
    """Correction of one triad: ``x_O = T diag(K) (x_S ± b)``.

    T: (3, 3) misalignment; K: (3,) scale (raw unit -> SI); b: (3,) bias in raw units.
    """

    T: FloatArray = field(default_factory=lambda: np.eye(3))
    K: FloatArray = field(default_factory=lambda: np.ones(3))
    b: FloatArray = field(default_factory=lambda: np.zeros(3))
    bias_sign: BiasSign = "plus"

    def __post_init__(self) -> None:
        self.T = np.asarray(self.T, dtype=float).reshape(3, 3)
        self.K = np.asarray(self.K, dtype=float).reshape(3)
        self.b = np.asarray(self.b, dtype=float).reshape(3)

    @property
    def M(self) -> FloatArray:
        """``T @ diag(K)`` (3, 3)."""
        return self.T * self.K[None, :]

    @property
    def offset(self) -> FloatArray:
        """The raw-unit offset added before ``M``: ``+b`` or ``-b`` by the sign convention."""
        return self.b if self.bias_sign == "plus" else -self.b

    def apply(self, raw_s: ArrayLike) -> FloatArray:
        """Corrected values (N, 3) from raw samples (N, 3)."""
        x = np.asarray(raw_s, dtype=float)
        return (x + self.offset) @ self.M.T

    def invert(self, corrected: ArrayLike) -> FloatArray:
        """Raw samples (N, 3) that correct to ``corrected`` (N, 3)."""
        x = np.linalg.solve(self.M, np.asarray(corrected, dtype=float).T).T
        return x - self.offset

    def with_sign(self, bias_sign: BiasSign) -> TriadModel:
        """The same correction written in the other bias sign convention."""
        if bias_sign == self.bias_sign:
            return replace(self)
        return TriadModel(self.T.copy(), self.K.copy(), -self.b, bias_sign)

    def to_dict(self) -> dict[str, Any]:
        return {
            "T": self.T.tolist(),
            "K": self.K.tolist(),
            "b": self.b.tolist(),
            "bias_sign": self.bias_sign,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str) -> TriadModel:
        try:
            sign = d.get("bias_sign", "plus")
            if sign not in ("plus", "minus"):
                raise ValueError(f"bias_sign must be 'plus' or 'minus', got {sign!r}")
            T = np.asarray(d["T"], dtype=float)
            K = np.asarray(d["K"], dtype=float)
            b = np.asarray(d["b"], dtype=float)
            if T.shape != (3, 3) or K.shape != (3,) or b.shape != (3,):
                raise ValueError(
                    f"expected T 3x3, K and b of 3; got {T.shape}, {K.shape}, {b.shape}"
                )
            if not (np.all(np.isfinite(T)) and np.all(np.isfinite(K)) and np.all(np.isfinite(b))):
                raise ValueError("non-finite value")
            return cls(T, K, b, sign)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: {exc}") from exc

    def save_imutk(self, path: str | Path) -> None:
        """Write an imu_tk ``.calib`` file: T (3 rows), K as a 3x3 matrix, then b, blank-line separated.

        imu_tk's model is ``T K (X - B)``, so a ``plus`` model is written with ``B = -b``.
        """
        m = self.with_sign("minus")
        fmt = "{:.10g}"
        rows = ["  ".join(fmt.format(v) for v in r) for r in m.T]
        krows = ["  ".join(fmt.format(v) for v in r) for r in np.diag(m.K)]
        brows = [fmt.format(v) for v in m.b]
        write_atomic(
            path, "\n".join(rows) + "\n\n" + "\n".join(krows) + "\n\n" + "\n".join(brows) + "\n\n"
        )

    @classmethod
    def load_imutk(cls, path: str | Path) -> TriadModel:
        """Read an imu_tk ``.calib`` file (21 numbers: T row-major, K row-major, B) as a ``minus`` model."""
        p = Path(path)
        try:
            vals = np.array(read_text(p).split(), dtype=float)
        except ValueError as exc:
            raise InputError(f"{p}: not an imu_tk .calib file (non-numeric token): {exc}") from exc
        if vals.size != 21:
            raise InputError(
                f"{p}: an imu_tk .calib file holds 21 numbers (T, K, B); found {vals.size}"
            )
        K = vals[9:18].reshape(3, 3)
        if np.any(np.abs(K - np.diag(np.diag(K))) > 0):
            raise InputError(f"{p}: the scale matrix K must be diagonal")
        return cls(vals[:9].reshape(3, 3), np.diag(K).copy(), vals[18:21], "minus")


@dataclass
class ImuCalibration:
    """A full IMU calibration, its uncertainty and provenance.

    cov_accel: (9, 9) covariance of the accelerometer parameters (order ``ACCEL_PARAM_NAMES``).
    cov_gyro: (9, 9) covariance of the gyro parameters (order ``GYRO_PARAM_NAMES``).
    cov_gyro_bias: (3, 3) covariance of the gyro bias, raw units squared.
    gyro_g_sensitivity: (3, 3) G, the gyro's response to specific force, rad/s per m/s^2 (None: none):
        ``omega = T K (x_S ± b) - G f`` with ``f`` the calibrated specific force of the same sample. A MEMS
        gyro's bias moves with the orientation in gravity (the xsens log: about 0.1 deg/s per g).
    accel_unit / gyro_unit: units of the raw input the model applies to; the output is m/s^2, rad/s.
    """

    accel: TriadModel
    gyro: TriadModel
    cov_accel: FloatArray | None = None
    cov_gyro: FloatArray | None = None
    cov_gyro_bias: FloatArray | None = None
    accel_unit: str = "m/s^2"
    gyro_unit: str = "rad/s"
    g: float = 9.80665
    sensor_id: str = ""
    date: str = field(
        default_factory=lambda: _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    )
    source: str = ""
    notes: dict[str, Any] = field(default_factory=dict)
    gyro_g_sensitivity: FloatArray | None = None

    def correct_accel(self, accel_s: ArrayLike) -> FloatArray:
        """accel_s: (N, 3) raw accelerometer samples -> (N, 3) body-frame specific force, m/s^2."""
        return self.accel.apply(accel_s)

    def correct_gyro(self, gyro_s: ArrayLike, accel_s: ArrayLike | None = None) -> FloatArray:
        """gyro_s: (N, 3) raw gyro samples -> (N, 3) body-frame angular rate, rad/s.

        accel_s: (N, 3) raw accelerometer samples of the same instants; needed when the calibration has a
        g-sensitivity term.
        """
        w = self.gyro.apply(gyro_s)
        if self.gyro_g_sensitivity is None:
            return w
        if accel_s is None:
            raise ValueError(
                "this calibration has a gyro g-sensitivity: correcting the gyro needs the accelerometer "
                "samples of the same instants"
            )
        return w - self.correct_accel(accel_s) @ self.gyro_g_sensitivity.T

    def correct(self, log: ImuLog) -> ImuLog:
        """The corrected log in SI units (m/s^2, rad/s), body frame."""
        if log.accel_unit != self.accel_unit or log.gyro_unit != self.gyro_unit:
            raise InputError(
                f"{log.source}: the calibration applies to accel in {self.accel_unit} and gyro in "
                f"{self.gyro_unit}; the log has {log.accel_unit} and {log.gyro_unit}"
            )
        out = ImuLog(
            log.t_ns.copy(),
            self.correct_accel(log.accel),
            self.correct_gyro(log.gyro, log.accel),
            "m/s^2",
            "rad/s",
            log.source,
            list(log.warnings),
        )
        return out

    def check_magnitudes(self, corrected: ImuLog, max_rate_rad_s: float = 35.0) -> None:
        """InputError when a corrected log cannot be what the calibration was made for: the median
        |accel| of any log of a robot on earth is near g (still, driving or walking), and no MEMS gyro
        measures over 2000 deg/s (35 rad/s). Either failing means the log's units differ from the
        calibration's (``units.accel_in`` / ``gyro_in``)."""
        if len(corrected) == 0:
            return
        na = float(np.median(np.linalg.norm(corrected.accel, axis=1)))
        if not 0.5 * self.g <= na <= 2.0 * self.g:
            raise InputError(
                f"{corrected.source}: corrected, the accelerations have a median magnitude of {na:.4g} "
                f"m/s^2 where gravity is {self.g:g}: the log is not in the calibration's accelerometer "
                f"unit ({self.accel_unit}); check --accel-unit and the calibration's units.accel_in"
            )
        ng = float(np.quantile(np.linalg.norm(corrected.gyro, axis=1), 0.99))
        if not ng <= max_rate_rad_s:
            raise InputError(
                f"{corrected.source}: corrected, 1 % of the angular rates exceed {ng:.4g} rad/s (over "
                f"{np.rad2deg(max_rate_rad_s):.0f} deg/s): the log is not in the calibration's gyro unit "
                f"({self.gyro_unit}); check --gyro-unit and the calibration's units.gyro_in"
            )

    @property
    def accel_params(self) -> FloatArray:
        """The 9 accelerometer parameters (``ACCEL_PARAM_NAMES``), bias in the model's sign."""
        a = misalignment_angles(self.accel.T)
        return np.concatenate([a[:3], self.accel.K, self.accel.b])

    @property
    def gyro_params(self) -> FloatArray:
        """The 9 gyro parameters (``GYRO_PARAM_NAMES``)."""
        return np.concatenate([misalignment_angles(self.gyro.T), self.gyro.K])

    def to_dict(self) -> dict[str, Any]:
        def cov(c: FloatArray | None) -> list[list[float]] | None:
            return None if c is None else np.asarray(c).tolist()

        return {
            "format": "imuslam-calibration/1",
            "sensor_id": self.sensor_id,
            "date": self.date,
            "source": self.source,
            "g": float(self.g),
            "units": {
                "accel_in": self.accel_unit,
                "gyro_in": self.gyro_unit,
                "accel_out": "m/s^2",
                "gyro_out": "rad/s",
            },
            "model": "x_O = T diag(K) (x_S + b) if bias_sign is plus, (x_S - b) if minus",
            "accel": self.accel.to_dict(),
            "gyro": self.gyro.to_dict(),
            "accel_param_names": list(ACCEL_PARAM_NAMES),
            "accel_params": self.accel_params.tolist(),
            "cov_accel": cov(self.cov_accel),
            "gyro_param_names": list(GYRO_PARAM_NAMES),
            "gyro_params": self.gyro_params.tolist(),
            "cov_gyro": cov(self.cov_gyro),
            "cov_gyro_bias": cov(self.cov_gyro_bias),
            "gyro_g_sensitivity": cov(self.gyro_g_sensitivity),
            "notes": self.notes,
        }

    def save_yaml(self, path: str | Path) -> None:
        """Write the calibration as YAML, atomically."""
        write_atomic(path, yaml.safe_dump(self.to_dict(), sort_keys=False))

    @classmethod
    def load_yaml(cls, path: str | Path) -> ImuCalibration:
        """Read a calibration written by :meth:`save_yaml`; a bad field is an InputError naming it."""
        p = Path(path)
        d = read_yaml(p, "an imuslam calibration (fields 'accel' and 'gyro')")
        if "accel" not in d or "gyro" not in d:
            raise InputError(
                f"{p}: not an imuslam calibration (fields 'accel' and 'gyro' expected)"
            )

        def cov(key: str, n: int) -> FloatArray | None:
            v = d.get(key)
            if v is None:
                return None
            try:
                c = np.asarray(v, dtype=float)
            except (TypeError, ValueError):
                raise InputError(
                    f"{p}: field '{key}' must be a {n}x{n} matrix of numbers"
                ) from None
            if c.shape != (n, n):
                raise InputError(f"{p}: field '{key}' must be {n}x{n}, got {c.shape}")
            return c

        def mapping(key: str, value: Any) -> dict[str, Any]:
            if not isinstance(value, dict):
                raise InputError(
                    f"{p}: field '{key}' must be a mapping, got {type(value).__name__} {value!r:.40}"
                )
            return value

        units = mapping("units", {} if d.get("units") is None else d["units"])
        unit_in: dict[str, str] = {}
        for key, allowed, default in (
            ("accel_in", ("m/s^2", "g", "counts"), "m/s^2"),
            ("gyro_in", ("rad/s", "deg/s", "counts"), "rad/s"),
        ):
            u = units.get(key, default)
            if u not in allowed:
                raise InputError(
                    f"{p}: field 'units.{key}' is {u!r}; expected one of {', '.join(allowed)}"
                )
            unit_in[key] = u
        g = d.get("g", 9.80665)
        if isinstance(g, bool) or not isinstance(g, int | float) or not 9.7 <= g <= 9.9:
            raise InputError(
                f"{p}: field 'g' is {g!r}; expected a gravity magnitude in [9.7, 9.9] m/s^2"
            )
        return cls(
            accel=TriadModel.from_dict(mapping("accel", d["accel"]), f"{p}: field 'accel'"),
            gyro=TriadModel.from_dict(mapping("gyro", d["gyro"]), f"{p}: field 'gyro'"),
            cov_accel=cov("cov_accel", 9),
            cov_gyro=cov("cov_gyro", 9),
            cov_gyro_bias=cov("cov_gyro_bias", 3),
            accel_unit=unit_in["accel_in"],
            gyro_unit=unit_in["gyro_in"],
            g=float(g),
            sensor_id=str(d.get("sensor_id", "")),
            date=str(d.get("date", "")),
            source=str(d.get("source", "")),
            notes=mapping("notes", {} if d.get("notes") is None else d["notes"]),
            gyro_g_sensitivity=cov("gyro_g_sensitivity", 3),
        )

    def export_imutk(self, acc_path: str | Path, gyro_path: str | Path) -> None:
        """Write imu_tk ``.calib`` files for the accelerometer and the gyroscope (imu_tk's model has no
        g-sensitivity term: it is left out)."""
        self.accel.save_imutk(acc_path)
        self.gyro.save_imutk(gyro_path)

    @classmethod
    def import_imutk(
        cls,
        acc_path: str | Path,
        gyro_path: str | Path,
        accel_unit: str = "counts",
        gyro_unit: str = "counts",
        g: float = 9.80665,
    ) -> ImuCalibration:
        """Read imu_tk ``.calib`` files (``minus`` convention)."""
        return cls(
            TriadModel.load_imutk(acc_path),
            TriadModel.load_imutk(gyro_path),
            accel_unit=accel_unit,
            gyro_unit=gyro_unit,
            g=g,
            source=f"imu_tk: {acc_path}, {gyro_path}",
        )
