"""IMU log readers: imu_tk text, EuRoC ``imu0/data.csv`` and generic CSV with a column mapping.

Every reader returns an :class:`ImuLog` with integer ``t_ns``, checked and repaired time stamps
(``io/timestamps.py``) and declared units; bad input is an InputError naming the file and line.
"""

from __future__ import annotations

import csv
import io
import logging
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.interfaces.imu import AccelUnit, GyroUnit, ImuLog
from imuslam.io.text import INT64_MAX, read_table, read_table_ns, read_text
from imuslam.io.timestamps import check_and_repair

log = logging.getLogger(__name__)

TimeUnit = Literal["s", "ms", "us", "ns", "auto"]
_TIME_SCALE = {"s": 1e9, "ms": 1e6, "us": 1e3, "ns": 1.0}


#: No IMU in any unit (m/s^2, g, rad/s, deg/s, 24-bit counts) reports a value this large: a larger one
#: is a corrupted field (1e308 would otherwise pass as finite and silently ruin every estimate).
MAX_ABS_SAMPLE = 1e7


def check_samples(
    accel: NDArray[np.float64],
    gyro: NDArray[np.float64],
    source: str,
    lines: NDArray[np.int64] | None = None,
) -> None:
    """InputError naming the line (or sample) of the first NaN, infinite or absurdly large value."""
    where = (lambda i: f"line {int(lines[i])}") if lines is not None else (lambda i: f"sample {i}")
    for name, x in (("accelerometer", accel), ("gyro", gyro)):
        nonfinite = ~np.isfinite(x).all(axis=1)
        if nonfinite.any():
            i = int(np.argmax(nonfinite))
            raise InputError(f"{source}, {where(i)}: the {name} value is NaN or infinite")
        big = (np.abs(x) > MAX_ABS_SAMPLE).any(axis=1)
        if big.any():
            i = int(np.argmax(big))
            v = float(x[i][np.argmax(np.abs(x[i]))])
            raise InputError(
                f"{source}, {where(i)}: the {name} value {v:g} is beyond any IMU's range "
                f"(|value| <= {MAX_ABS_SAMPLE:g} in any unit)"
            )


def _to_ns(
    t: NDArray[np.float64], unit: TimeUnit, source: str, lines: NDArray[np.int64] | None = None
) -> NDArray[np.int64]:
    if unit == "auto":
        d = np.diff(t)
        step = float(np.median(d[d > 0])) if np.any(d > 0) else 1.0
        # IMU rates 1 Hz .. 10 kHz: the median step decides the unit.
        unit = "s" if step < 1.0 else "ms" if step < 100 else "us" if step < 1e5 else "ns"
        log.info("%s: time unit guessed as %s (median step %g)", source, unit, step)
    big = np.abs(t) * _TIME_SCALE[unit] >= INT64_MAX
    if big.any():
        i = int(np.argmax(big))
        at = f"line {int(lines[i])}" if lines is not None else f"sample {i}"
        raise InputError(
            f"{source}, {at}: time {t[i]:g} {unit} is beyond the int64 nanosecond range (the year 2262)"
        )
    if unit == "ns":
        return np.round(t).astype(np.int64)
    t0 = np.floor(t[0])
    return (np.round(t0 * _TIME_SCALE[unit]) + np.round((t - t0) * _TIME_SCALE[unit])).astype(
        np.int64
    )


def guess_units(
    accel: NDArray[np.float64], gyro: NDArray[np.float64]
) -> tuple[AccelUnit, GyroUnit]:
    """Units from magnitudes: median |a| near 1 -> g, near 9.8 -> m/s^2, above 100 -> counts;
    gyro in counts with counts, else deg/s when the 99th percentile of |w| exceeds 20 (rad/s would be
    over 1100 deg/s), else rad/s."""
    na = float(np.median(np.linalg.norm(accel, axis=1)))
    if na > 100:
        return "counts", "counts"
    au: AccelUnit = "g" if na < 3.0 else "m/s^2"
    ng = float(np.quantile(np.linalg.norm(gyro, axis=1), 0.99))
    return au, ("deg/s" if ng > 20 else "rad/s")


def _finish(
    t: NDArray[np.float64],
    accel: NDArray[np.float64],
    gyro: NDArray[np.float64],
    lines: NDArray[np.int64] | None,
    source: str,
    time_unit: TimeUnit,
    accel_unit: AccelUnit | None,
    gyro_unit: GyroUnit | None,
) -> ImuLog:
    check_samples(accel, gyro, source, lines)
    t_ns = _to_ns(t, time_unit, source, lines)
    tc = check_and_repair(t_ns, source, lines)
    warnings = list(tc.warnings)
    if accel_unit is None or gyro_unit is None:
        ga, gg = guess_units(accel, gyro)
        if accel_unit is None:
            accel_unit = ga
            warnings.append(
                f"{source}: accelerometer unit not given; guessed {ga} from the magnitudes"
            )
        if gyro_unit is None:
            gyro_unit = gg
            warnings.append(f"{source}: gyro unit not given; guessed {gg} from the magnitudes")
        for w in warnings[len(tc.warnings) :]:
            log.warning(w)
    return ImuLog(tc.t_ns, accel, gyro, accel_unit, gyro_unit, source, warnings)


def read_imutk(
    acc_path: str | Path,
    gyro_path: str | Path | None = None,
    *,
    time_unit: TimeUnit = "s",
    accel_unit: AccelUnit | None = None,
    gyro_unit: GyroUnit | None = None,
) -> ImuLog:
    """imu_tk text: ``t x y z`` per line in two files (accel, gyro), or one file of 7 (``t a g``) or
    10 columns (``t a g m``, the magnetometer is dropped). Whitespace or commas.

    Two files must share their time stamps; if they do not (different rates), the gyro is interpolated
    linearly onto the accelerometer's stamps within their common span.
    """
    src = str(acc_path)
    if gyro_path is None:
        data, lines = read_table(acc_path, (7, 10))
        return _finish(
            data[:, 0], data[:, 1:4], data[:, 4:7], lines, src, time_unit, accel_unit, gyro_unit
        )
    a, la = read_table(acc_path, 4)
    g, lg = read_table(gyro_path, 4)
    for name, d, ln in ((acc_path, a, la), (gyro_path, g, lg)):
        back = np.flatnonzero(np.diff(d[:, 0]) < 0)
        if back.size:
            i = int(back[0]) + 1
            raise InputError(
                f"{name}: time goes backwards at line {int(ln[i])} ({d[i, 0]:g} after {d[i - 1, 0]:g}); "
                "expected non-decreasing timestamps"
            )
    src = f"{acc_path} + {gyro_path}"
    if a.shape[0] == g.shape[0] and np.array_equal(a[:, 0], g[:, 0]):
        return _finish(a[:, 0], a[:, 1:], g[:, 1:], la, src, time_unit, accel_unit, gyro_unit)
    lo, hi = max(a[0, 0], g[0, 0]), min(a[-1, 0], g[-1, 0])
    if not hi > lo:
        raise InputError(f"{src}: the accelerometer and gyro files do not overlap in time")
    keep = (a[:, 0] >= lo) & (a[:, 0] <= hi)
    gi = np.stack([np.interp(a[keep, 0], g[:, 0], g[:, j]) for j in (1, 2, 3)], axis=1)
    out = _finish(a[keep, 0], a[keep, 1:], gi, la[keep], src, time_unit, accel_unit, gyro_unit)
    out.warnings.append(
        f"{src}: gyro interpolated onto the accelerometer stamps ({keep.sum()} samples)"
    )
    return out


def read_euroc(path: str | Path) -> ImuLog:
    """EuRoC ``imu0/data.csv``: ``timestamp [ns], w_x, w_y, w_z [rad/s], a_x, a_y, a_z [m/s^2]``."""
    p = Path(path)
    if p.is_dir():
        p = p / "mav0" / "imu0" / "data.csv" if (p / "mav0").is_dir() else p / "imu0" / "data.csv"
    if not p.is_file():
        raise InputError(f"{p}: no such file (a EuRoC imu0/data.csv or its dataset folder)")
    # float64 holds ns stamps of 2014 to ~256 ns: the stamps are read as integers, exactly.
    data, lines, t_ns = read_table_ns(p, 7)
    check_samples(data[:, 4:7], data[:, 1:4], str(p), lines)
    tc = check_and_repair(t_ns, str(p), lines)
    return ImuLog(tc.t_ns, data[:, 4:7], data[:, 1:4], "m/s^2", "rad/s", str(p), list(tc.warnings))


def read_csv(
    path: str | Path,
    columns: dict[str, str | int],
    *,
    time_unit: TimeUnit = "auto",
    accel_unit: AccelUnit | None = None,
    gyro_unit: GyroUnit | None = None,
    delimiter: str = ",",
) -> ImuLog:
    """A CSV with a header and a column mapping ``{t, ax, ay, az, gx, gy, gz}`` -> name or index.

    Rows whose mapped fields are empty (e.g. interleaved rows of another message type) are skipped and
    counted in a warning; a non-numeric field is an InputError naming the line and column.
    """
    p = Path(path)
    need = ("t", "ax", "ay", "az", "gx", "gy", "gz")
    missing = [k for k in need if k not in columns]
    if missing:
        raise InputError(
            f"{p}: the column mapping lacks {', '.join(missing)} (keys {', '.join(need)})"
        )
    text = read_text(p)
    try:
        with io.StringIO(text, newline="") as fh:
            reader = csv.reader(fh, delimiter=delimiter)
            header = next(reader, None)
            if header is None:
                raise InputError(f"{p}: the file is empty")
            idx: list[int] = []
            for k in need:
                c = columns[k]
                if isinstance(c, int):
                    idx.append(c)
                elif c in header:
                    idx.append(header.index(c))
                else:
                    raise InputError(
                        f"{p}: no column '{c}' (for {k}) in the header: {', '.join(header)}"
                    )
            rows: list[list[str]] = []
            lines: list[int] = []
            skipped = 0
            for ln, row in enumerate(reader, start=2):
                if not row:
                    continue
                try:
                    vals = [row[i].strip() for i in idx]
                except IndexError:
                    raise InputError(
                        f"{p}, line {ln}: {len(row)} columns; expected at least {max(idx) + 1}"
                    ) from None
                if any(v == "" for v in vals):
                    skipped += 1
                    continue
                rows.append(vals)
                lines.append(ln)
    except csv.Error as exc:
        raise InputError(f"{p}: not a CSV file ({exc})") from None
    if not rows:
        raise InputError(f"{p}: no row has all of the mapped columns filled")
    try:
        data = np.array(rows, dtype=float)
    except ValueError:
        for r, ln in zip(rows, lines, strict=True):
            for name, v in zip(need, r, strict=True):
                try:
                    float(v)
                except ValueError:
                    raise InputError(
                        f"{p}, line {ln}: '{v}' in column {name} is not a number"
                    ) from None
        raise
    bad = ~np.isfinite(data).all(axis=1)
    if bad.any():
        raise InputError(f"{p}, line {lines[int(np.argmax(bad))]}: a value is NaN or infinite")
    out = _finish(
        data[:, 0],
        data[:, 1:4],
        data[:, 4:7],
        np.asarray(lines),
        str(p),
        time_unit,
        accel_unit,
        gyro_unit,
    )
    if skipped:
        msg = f"{p}: skipped {skipped} rows with empty mapped fields"
        log.info(msg)
        out.warnings.append(msg)
    return out
