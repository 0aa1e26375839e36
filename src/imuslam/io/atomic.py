"""Atomic output: a file is either absent, the previous version, or complete; never partly written."""

from __future__ import annotations

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
    """
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp_dir = Path(tempfile.mkdtemp(dir=p.parent, prefix=f".{p.name}."))
    tmp = tmp_dir / p.name
    try:
        yield tmp
        if tmp.is_dir():
            if p.exists():
                shutil.rmtree(p)
            os.replace(tmp, p)
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
