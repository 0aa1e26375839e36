"""Helpers shared by the commands: error reporting, log loading options, result tables."""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Callable, Iterable
from enum import Enum, StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar, cast

import typer
from rich.console import Console
from rich.table import Table

from imuslam.errors import ImuslamError, InputError

if TYPE_CHECKING:  # the readers (rosbags, scipy) load only when a command reads a log
    from imuslam.interfaces.imu import AccelUnit, GyroUnit, ImuLog
    from imuslam.io.load import ImuFormat

# emoji off: no output here uses ":name:" codes, and their table costs 13 ms of start-up to load
console = Console(emoji=False)
err_console = Console(stderr=True, emoji=False)
F = TypeVar("F", bound=Callable[..., Any])


# Options typed ``str`` that name an input file or folder (the others are topics, names, choices).
_PATH_STR_OPTIONS = ("dataset", "gt", "noise")


RRD_HELP = (
    "also save a rerun recording of the run to this new .rrd file (pip install 'imuslam\\[viz]')"
)
VIEWER_HELP = "stream the run live to a rerun viewer spawned here (pip install 'imuslam\\[viz]')"

#: The outputs a command may take: the results folder, and the viewer's recording.
_OUT_OPTIONS = ("out", "rrd")


def check_out_against_inputs(kwargs: dict[str, Any]) -> None:
    """Refuse an ``out`` (or ``rrd``) that is, holds or lies inside one of the command's inputs (every
    ``Path`` parameter, and the ``str`` ones of :data:`_PATH_STR_OPTIONS`), before any work."""
    outs = [(n, kwargs[n]) for n in _OUT_OPTIONS if isinstance(kwargs.get(n), Path)]
    if not outs:
        return
    from imuslam.io.results import check_not_input

    inputs: list[tuple[str, Path | str | None]] = []
    for name, v in kwargs.items():
        what = f"the input ({name.replace('_', '-')})"
        if name in _OUT_OPTIONS:
            continue
        if isinstance(v, Path) or (name in _PATH_STR_OPTIONS and isinstance(v, str)):
            inputs.append((what, v))
        elif isinstance(v, list | tuple):
            inputs += [(what, x) for x in v if isinstance(x, Path)]
    for name, out in outs:
        check_not_input(out, inputs, option=f"--{name}")


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM: the run stops, its temporary files are removed, exit 128 + the signal."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _interrupt(exc: BaseException) -> Interrupted | None:
    """The interrupt behind ``exc``: itself, or the cause of an error it became (a SystemError raised
    when the signal arrived inside a compiled kernel)."""
    from imuslam.errors import raise_if_interrupted

    try:
        raise_if_interrupted(exc)
    except Interrupted as intr:
        return intr
    except KeyboardInterrupt:
        return Interrupted(2)
    return None


def install_signal_handlers() -> None:
    """SIGTERM (and SIGINT) raise :class:`Interrupted` in the main thread, so every ``with`` block
    (results folders, progress bars, Dask clients) unwinds and removes what it had started."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return

    def handler(signum: int, frame: Any) -> None:
        signal.signal(signum, signal.SIG_IGN)  # a second signal while unwinding is not a new error
        raise Interrupted(signum)

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)


def friendly_errors(fn: F) -> F:
    """Turn an imuslam error into a one-line message on stderr and its exit code (no traceback); an
    interrupt (SIGINT, SIGTERM) into one line and exit 130 / 143 after the clean-up."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        show_warnings_once()
        try:
            check_out_against_inputs(kwargs)
            return fn(*args, **kwargs)
        except ImuslamError as exc:
            _print_error(str(exc))
            raise typer.Exit(exc.exit_code) from None
        except OSError as exc:  # a file that vanished or cannot be read or written mid-run
            where = exc.filename if exc.filename is not None else "a file"
            _print_error(f"{where}: {exc.strerror or exc}")
            raise typer.Exit(2) from None
        except KeyboardInterrupt as exc:
            _exit_interrupted(_interrupt(exc))
        except (
            MemoryError
        ):  # a setting that scales an allocation past the machine (a voxel cap, a blur)
            _print_error("out of memory: the input or a setting asks for more than this machine has "
                         "(imuslam --verbose shows where)")  # fmt: skip
            raise typer.Exit(3) from None
        except Exception as exc:
            intr = _interrupt(exc)  # the signal arrived inside a compiled kernel
            if intr is not None:
                _exit_interrupted(intr)
            # a solver met a singular system the checks missed (numpy is loaded if it raised one)
            np = sys.modules.get("numpy")
            if np is None or not isinstance(exc, np.linalg.LinAlgError):
                raise
            logging.getLogger(__name__).debug("where the estimator failed", exc_info=exc)
            _print_error(f"an estimator failed: {exc} (imuslam --verbose shows where)")
            raise typer.Exit(3) from None
        finally:  # a child still parsing a file that was never read (see prefetch_log)
            text = sys.modules.get("imuslam.io.text")
            if text is not None:
                text.cancel_prefetch()

    return wrapper  # type: ignore[return-value]


def _exit_interrupted(intr: Interrupted | None) -> None:
    signum = intr.signum if intr is not None else 2
    name = {2: "SIGINT", 15: "SIGTERM"}.get(signum, f"signal {signum}")
    _print_error(f"interrupted ({name}); the results of this run were not written")
    raise typer.Exit(128 + signum) from None


def _print_error(msg: str) -> None:
    # markup off: a path or value in the message must print as it is ("[1, 2]" is not a style)
    err_console.print("[bold red]error:[/] ", end="")
    err_console.print(msg, markup=False, highlight=False, soft_wrap=True)


class ImuFormatChoice(StrEnum):
    """``--format`` of the IMU readers (``imuslam.io.load.FORMATS``)."""

    auto = "auto"
    imutk = "imutk"
    euroc = "euroc"
    csv = "csv"
    bag = "bag"
    matlab = "matlab"


class AccelUnitChoice(StrEnum):
    m_s2 = "m/s^2"
    g = "g"
    counts = "counts"


class GyroUnitChoice(StrEnum):
    rad_s = "rad/s"
    deg_s = "deg/s"
    counts = "counts"


class BiasSign(StrEnum):
    plus = "plus"
    minus = "minus"


def value(choice: Enum | None) -> str | None:
    """The string of an Enum option (None stays None)."""
    return None if choice is None else str(choice.value)


COLUMN_KEYS = ("t", "ax", "ay", "az", "gx", "gy", "gz")
ACCEL_UNITS = ("m/s^2", "g", "counts")
GYRO_UNITS = ("rad/s", "deg/s", "counts")


def parse_columns(spec: str | None) -> dict[str, str | int] | None:
    """``t=time,ax=acc_x,...`` (names or 0-based indices) -> a column mapping."""
    if not spec:
        return None
    out: dict[str, str | int] = {}
    for part in spec.split(","):
        if "=" not in part:
            raise InputError(
                f"--columns: '{part}' is not key=column (keys t, ax, ay, az, gx, gy, gz)"
            )
        k, v = (s.strip() for s in part.split("=", 1))
        if k not in COLUMN_KEYS or not v:
            raise InputError(
                f"--columns: '{part}'; expected key=column with a key of {', '.join(COLUMN_KEYS)}"
            )
        out[k] = int(v) if v.isdigit() else v
    return out


def prefetch_log(acc: Path, gyro: Path | None, fmt: str) -> None:
    """For imu_tk text in two files, start parsing both beside this process's imports (see
    :func:`imuslam.io.text.prefetch_tables`); :func:`load_log` then takes the parsed tables."""
    if gyro is None or fmt not in ("auto", "imutk"):
        return
    from imuslam.io.load import detect_format

    try:
        if detect_format(acc) != "imutk" or detect_format(gyro) != "imutk":
            return
    except InputError:  # load_log reports it
        return
    from imuslam.io.text import prefetch_tables

    prefetch_tables([acc, gyro], 4)


def check_log_options(fmt: str, accel_unit: str | None, gyro_unit: str | None) -> None:
    """The log-reading options named when wrong, before any file is read."""
    from imuslam.io.load import FORMATS

    if accel_unit is not None and accel_unit not in ("m/s^2", "g", "counts"):
        raise InputError(f"--accel-unit: '{accel_unit}'; expected m/s^2, g or counts")
    if gyro_unit is not None and gyro_unit not in ("rad/s", "deg/s", "counts"):
        raise InputError(f"--gyro-unit: '{gyro_unit}'; expected rad/s, deg/s or counts")
    if fmt not in FORMATS:
        raise InputError(f"--format: '{fmt}'; expected one of {', '.join(FORMATS)}")


def load_log(
    acc: Path,
    gyro: Path | None,
    fmt: str,
    topic: str | None,
    accel_unit: str | None,
    gyro_unit: str | None,
    columns: str | None,
) -> ImuLog:
    """Load a log from the command-line options (see :func:`imuslam.io.load.load_imu`)."""
    from imuslam.io.load import load_imu

    check_log_options(fmt, accel_unit, gyro_unit)
    return load_imu(
        acc,
        gyro,
        cast("ImuFormat", fmt),
        topic,
        cast("AccelUnit | None", accel_unit),
        cast("GyroUnit | None", gyro_unit),
        parse_columns(columns),
    )


def write_json(path: Path, data: Any) -> None:
    """Standard JSON (a non-finite number is written as null), atomically."""
    from imuslam.io.results import write_json as _write

    _write(path, data)


def table(title: str, columns: list[str], rows: list[list[str]]) -> Table:
    """A result table. Headers and cells are plain text, never markup (a unit "[m]" would vanish as a
    style tag); a long cell wraps (``overflow="fold"``) rather than being cut with an ellipsis."""
    from rich.text import Text

    t = Table(title=Text(title))
    for i, c in enumerate(columns):
        left = i == 0  # the row's label
        t.add_column(Text(c), justify="left" if left else "right", overflow="fold")
    for r in rows:
        t.add_row(*(Text(x) for x in r))
    return t


# the warnings this command has shown, each with the log record that showed it (None: printed); each
# is shown once, however it arrives
_SHOWN: dict[str, logging.LogRecord | None] = {}


class _OnceFilter(logging.Filter):
    """Drops a log message already shown by this command (a reader logs what it also returns); the
    first record of a message passes every handler."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.WARNING:
            return True
        msg = record.getMessage()
        first = _SHOWN.setdefault(msg, record)
        return first is record


def show_warnings_once() -> None:
    """From now on this command shows each warning once: the log handlers drop a repeated message and
    :func:`print_warnings` skips one already logged (called at each command's start)."""
    _SHOWN.clear()
    for h in logging.getLogger().handlers:
        if not any(isinstance(f, _OnceFilter) for f in h.filters):
            h.addFilter(_OnceFilter())


def print_warnings(warnings: Iterable[str]) -> None:
    """Each of ``warnings`` on the terminal, unless it was already shown (logged by the reader)."""
    for w in warnings:
        if w in _SHOWN:
            continue
        _SHOWN[w] = None
        console.print(f"warning: {w}", markup=False, highlight=False, soft_wrap=True)


def show_progress(progress: bool) -> bool:
    """Whether to draw a progress bar: asked for (``--progress``, the default) and stderr a terminal,
    so a log written to a file or a pipe is not flooded with redrawn bars."""
    return progress and sys.stderr.isatty()


def progress_option() -> Any:
    """The ``--progress/--no-progress`` option of every command that shows progress."""
    return typer.Option(
        True, "--progress/--no-progress", help="progress bar on stderr (drawn only on a terminal)"
    )


FORMAT_HELP = "input format: auto, imutk, euroc, csv, bag or matlab (v7.3 accelBuffer / gyroBuffer)"
