"""Atomic output: a file is either absent, the previous version, or complete; never partly written."""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is renamed onto ``path``, on error removed.

    Use for writers that need a file name (a bag, a PNG): ``with atomic_path(out) as tmp: write(tmp)``.
    A file replaces ``path`` in one rename. A folder (a ROS 2 bag) is renamed onto ``path`` only if
    nothing is there: an existing ``path`` is never removed (FileExistsError), so a folder of the user's
    cannot be lost. A set of results for an existing folder goes through
    :func:`imuslam.io.results.results_folder`, which adds files instead of replacing the folder.
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp_dir = Path(tempfile.mkdtemp(dir=p.parent, prefix=f".{p.name}."))
    tmp = tmp_dir / p.name
    try:
        yield tmp
        if tmp.is_dir():
            if os.path.lexists(p):
                raise FileExistsError(errno.EEXIST, "exists; a folder is never replaced", str(p))
            os.rename(tmp, p)
        else:
            os.replace(tmp, p)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)


def write_atomic(path: str | Path, data: str | bytes) -> None:
    """Write text or bytes to ``path`` through a temporary file, fsync and rename."""
    with atomic_path(path) as tmp:
        mode = "wb" if isinstance(data, bytes) else "w"
        with open(tmp, mode) as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
