"""Option checks at the command line's boundary: every value is validated before any work starts.

Each factory returns a typer option callback. A bad value raises ``typer.BadParameter``, which click
reports as one message naming the option (``Invalid value for '--g': ...``) with exit code 2, before the
command body runs. ``out_folder`` / ``out_file`` preflight an output path the same way (see
:func:`imuslam.io.results.check_out_dir`).

    g: float = typer.Option(9.80665, "--g", callback=validate.gravity())
    seed: int = typer.Option(0, callback=validate.integer(lo=0))
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TypeVar

import typer

from imuslam.errors import InputError
from imuslam.io.results import OutKind, check_out_dir

T = TypeVar("T")

#: Gravity magnitudes on earth's surface: 9.780 (equator, sea level) .. 9.832 (poles); the band keeps a
#: margin for altitude and for local anomalies, and rejects a value in another unit (98.1, 1.0, -9.8).
G_BAND = (9.7, 9.9)
#: The largest seed every generator here accepts (numpy's legacy ``RandomState`` and numba's take 32 bits).
SEED_MAX = 2**32 - 1


def _fmt_range(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    if lo is not None and hi is not None:
        return f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {lo:g}"
    if hi is not None:
        return f"{'<' if hi_open else '<='} {hi:g}"
    return "finite"


def number(
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
    unit: str = "",
    what: str = "a finite number",
) -> Callable[[float | None], float | None]:
    """A callback accepting a finite float within ``[lo, hi]`` (open ends with ``lo_open`` / ``hi_open``);
    None (an option left out) passes."""
    rng = _fmt_range(lo, hi, lo_open, hi_open)
    u = f" {unit}" if unit else ""

    def check(value: float | None) -> float | None:
        if value is None:
            return None
        ok = math.isfinite(value)
        if ok and lo is not None:
            ok = value > lo if lo_open else value >= lo
        if ok and hi is not None:
            ok = value < hi if hi_open else value <= hi
        if not ok:
            raise typer.BadParameter(f"{value:g}{u}; expected {what} {rng}{u}".replace("  ", " "))
        return value

    return check


def positive(unit: str = "", hi: float | None = None) -> Callable[[float | None], float | None]:
    """A finite float > 0 (and <= ``hi`` when given)."""
    return number(0.0, hi, lo_open=True, unit=unit, what="a positive finite number")


def gravity() -> Callable[[float | None], float | None]:
    """A gravity magnitude on earth, m/s^2, in :data:`G_BAND`."""
    return number(*G_BAND, unit="m/s^2", what="a gravity magnitude on earth")


def integer(
    lo: int | None = None, hi: int | None = None, also: tuple[int, ...] = ()
) -> Callable[[int | None], int | None]:
    """An int within ``[lo, hi]``, or one of ``also`` (e.g. 0 for "none")."""
    rng = (
        f"in [{lo}, {hi}]"
        if lo is not None and hi is not None
        else _fmt_range(lo, hi, False, False)
    ) + "".join(f" or {a}" for a in also)

    def check(value: int | None) -> int | None:
        if value is None or value in also:
            return value
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise typer.BadParameter(f"{value}; expected an integer {rng}")
        return value

    return check


def choice(values: Iterable[T]) -> Callable[[T | None], T | None]:
    """One of ``values`` (for options typed ``str``; an Enum option is checked by click itself)."""
    allowed = list(values)

    def check(value: T | None) -> T | None:
        if value is None:
            return None
        if value not in allowed:
            raise typer.BadParameter(f"'{value}'; expected one of {', '.join(map(str, allowed))}")
        return value

    return check


def _out(kind: OutKind) -> Callable[[Path | None], Path | None]:
    def check(value: Path | None) -> Path | None:
        if value is None:
            return None
        try:
            check_out_dir(value, kind, option="")
        except InputError as exc:
            raise typer.BadParameter(str(exc)) from None
        return value

    return check


def out_folder() -> Callable[[Path | None], Path | None]:
    """A results folder that can be created or written (checked before any work)."""
    return _out("folder")


def out_file() -> Callable[[Path | None], Path | None]:
    """An output file (or bag) that can be created (checked before any work)."""
    return _out("file")


def out_any() -> Callable[[Path | None], Path | None]:
    """An output that may be a file or a folder, decided later (e.g. by the input's format)."""
    return _out("any")
