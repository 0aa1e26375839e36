"""The kinds of aiding the alignment filters take, one name for the Python callers and one code for the
compiled kernels."""

from __future__ import annotations

from enum import StrEnum


class AidingKind(StrEnum):
    """Position (m, in n), velocity (m/s, in n) or ``zupt`` (the IMU is still: zero velocity and zero
    angular rate). Equal to its name as a string (``AidingKind.ZUPT == "zupt"``)."""

    POSITION = "position"
    VELOCITY = "velocity"
    ZUPT = "zupt"

    @property
    def code(self) -> int:
        """The kernels' code: 0 position, 1 velocity, 2 zupt."""
        return _CODES[self]


_CODES = {AidingKind.POSITION: 0, AidingKind.VELOCITY: 1, AidingKind.ZUPT: 2}
