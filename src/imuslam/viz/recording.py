"""Opening a rerun recording: saved to a file through the results writer's rules, streamed to a
spawned viewer, or both."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError

#: The one line shown when the optional viewer package is missing.
HINT = "the viewer needs rerun-sdk: pip install 'imuslam[viz]'"

TIMELINE = "sensor_time"


def require_rerun() -> Any:
    """The ``rerun`` module, or an InputError (exit 2) with the install hint."""
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
            try:
                rr.spawn(connect=False, recording=rec)
            except Exception as exc:  # no viewer binary, no display
                raise InputError(f"--viewer: the rerun viewer did not start ({exc})") from None
            sinks.append(rr.GrpcSink())
        rec.set_sinks(*sinks)
        rr.set_log_time_enabled(False, recording=rec)
        rec.send_recording_name(name)
        try:
            yield rec
        finally:
            rec.flush()
            rec.disconnect()
