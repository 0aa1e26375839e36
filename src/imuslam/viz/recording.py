"""Opening a rerun recording: saved to a file through the results writer's rules, streamed to a
spawned viewer, or both."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError

log = logging.getLogger(__name__)

#: The one line shown when the optional viewer package is missing.
HINT = "the viewer needs rerun-sdk: pip install 'imuslam[viz]'"

TIMELINE = "sensor_time"


def require_rerun() -> Any:
    """The ``rerun`` module, or an InputError (exit 2) with the install hint."""
    # rerun loads pandas, which loads numexpr, which logs its thread count at INFO
    logging.getLogger("numexpr").setLevel(logging.WARNING)
    try:
        import rerun as rr
    except ImportError:
        raise InputError(HINT) from None
    return rr


def set_time(rec: Any, t_ns: int, step: int | None = None, step_name: str = "scan") -> None:
    """Put ``rec`` at the sensor's stamp ``t_ns`` (and at ``step`` on the ``step_name`` counter)."""
    rec.set_time(TIMELINE, timestamp=np.datetime64(int(t_ns), "ns"))
    if step is not None:
        rec.set_time(step_name, sequence=int(step))


def time_column(rr: Any, t_ns: NDArray[np.int64]) -> Any:
    """A ``sensor_time`` column for ``send_columns``."""
    return rr.TimeColumn(TIMELINE, timestamp=np.asarray(t_ns, np.int64).astype("datetime64[ns]"))


def spawn_viewer(rr: Any, rec: Any) -> None:
    """Start the rerun viewer (the one installed beside this Python first, so an unactivated
    virtual environment finds it); an InputError in one line when it cannot start."""
    import os
    import shutil
    import sys

    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        raise InputError(
            "the rerun viewer needs a display (DISPLAY and WAYLAND_DISPLAY are unset); write a "
            "recording with --rrd and open it where there is one (rerun FILE.rrd)"
        )
    beside = Path(sys.executable).parent / "rerun"
    exe = str(beside) if beside.is_file() else shutil.which("rerun")
    if exe is None:
        raise InputError(f"the rerun viewer is not installed ({HINT}), or write a file with --rrd")
    try:
        rr.spawn(connect=False, recording=rec, executable_path=exe)
    except Exception as exc:  # the viewer failed to start
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"the rerun viewer did not start: {first}") from None


@contextmanager
def open_recording(name: str, rrd: Path | None, viewer: bool) -> Iterator[Any]:
    """A ``rerun.RecordingStream`` named ``name`` writing to ``rrd`` (a new file, appearing only when
    the block ends without error, as :func:`imuslam.io.results.results_file`) and/or streaming to a
    viewer spawned here; None when neither is asked (nothing of rerun is imported then)."""
    if rrd is None and not viewer:
        yield None
        return
    rr = require_rerun()
    with ExitStack() as stack:
        sinks: list[Any] = []
        if rrd is not None:
            from imuslam.io.results import results_file

            tmp = stack.enter_context(results_file(rrd, option="--rrd"))
            sinks.append(rr.FileSink(str(tmp)))
        rec = rr.RecordingStream("imuslam", recording_id=None)
        if viewer:
            spawn_viewer(rr, rec)
            sinks.append(rr.GrpcSink())
        rec.set_sinks(*sinks)
        rr.set_log_time_enabled(False, recording=rec)
        rec.send_recording_name(name)
        try:
            yield rec
        finally:
            import sys

            in_flight = sys.exc_info()[1]  # the block's own error goes on as it is
            try:
                rec.flush()
            except RuntimeError as exc:
                rec.disconnect()
                first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
                if in_flight is None and viewer:  # the viewer went away: the file sink is complete
                    log.warning(
                        "the rerun viewer could not be reached (%s); the results are complete",
                        first,
                    )
                elif in_flight is None:
                    raise InputError(
                        f"--rrd {rrd}: the recording could not be written ({first})"
                    ) from None
            else:
                rec.disconnect()
