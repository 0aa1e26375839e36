"""Calibration history: one YAML file per version in a folder, written atomically, looked up by date.

Each version is ``v0001.yaml``, ``v0002.yaml``, ... (the calibration's own YAML, whose ``date`` field is
its time of validity). The folder is the index: a crash while writing leaves no partial file, and every
earlier version stays readable.
"""

from __future__ import annotations

import datetime as dt
import re
from dataclasses import dataclass
from pathlib import Path

from imuslam.errors import InputError
from imuslam.imu.model import ImuCalibration

_NAME = re.compile(r"^v(\d{4,})\.yaml$")


def _parse_date(s: str) -> dt.datetime:
    try:
        d = dt.datetime.fromisoformat(s)
    except ValueError as exc:
        raise InputError(f"date '{s}' is not ISO 8601") from exc
    return d if d.tzinfo else d.replace(tzinfo=dt.UTC)


@dataclass
class CalibrationHistory:
    """Versions of an IMU's calibration in ``folder``."""

    folder: Path

    def __post_init__(self) -> None:
        self.folder = Path(self.folder)

    def versions(self) -> list[int]:
        if not self.folder.is_dir():
            return []
        return sorted(int(m.group(1)) for p in self.folder.iterdir() if (m := _NAME.match(p.name)))

    def path(self, version: int) -> Path:
        return self.folder / f"v{version:04d}.yaml"

    def add(self, cal: ImuCalibration) -> int:
        """Store ``cal`` as the next version (atomically); returns its number."""
        v = (self.versions() or [0])[-1] + 1
        cal.notes = {**cal.notes, "version": v}
        cal.save_yaml(self.path(v))
        return v

    def load(self, version: int) -> ImuCalibration:
        return ImuCalibration.load_yaml(self.path(version))

    def latest(self) -> ImuCalibration | None:
        vs = self.versions()
        return self.load(vs[-1]) if vs else None

    def entries(self) -> list[tuple[int, dt.datetime]]:
        return [(v, _parse_date(self.load(v).date)) for v in self.versions()]

    def in_force(self, when: str | dt.datetime) -> ImuCalibration | None:
        """The newest calibration dated at or before ``when`` (None if all are later)."""
        t = _parse_date(when) if isinstance(when, str) else when
        best = [(d, v) for v, d in self.entries() if d <= t]
        return self.load(max(best)[1]) if best else None

    def closest(self, when: str | dt.datetime) -> ImuCalibration | None:
        """The calibration whose date is nearest to ``when``."""
        t = _parse_date(when) if isinstance(when, str) else when
        e = self.entries()
        if not e:
            return None
        return self.load(min(e, key=lambda x: abs((x[1] - t).total_seconds()))[0])
