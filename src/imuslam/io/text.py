"""Reading numeric text tables with errors that name the file and line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError


def read_table(
    path: str | Path,
    n_cols: int | tuple[int, ...],
    comment: str = "#%",
    skip_header: bool | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Numeric rows (N, C) of a whitespace- or comma-separated file and their 1-based line numbers.

    n_cols: the accepted column count(s); a row with another count is an InputError naming its line.
    Blank lines and lines starting with a ``comment`` character are skipped; a first line that is not
    numeric is taken as a header when ``skip_header`` is None.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise InputError(f"{p}: not a text file ({exc.reason})") from exc
    allowed = (n_cols,) if isinstance(n_cols, int) else n_cols
    rows: list[list[str]] = []
    lines: list[int] = []
    first = True
    for i, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s[0] in comment:
            continue
        toks = s.replace(",", " ").split()
        if first:
            first = False
            if skip_header or (skip_header is None and not _numeric(toks[0])):
                continue
        rows.append(toks)
        lines.append(i)
    if not rows:
        raise InputError(f"{p}: the file holds no data rows")
    counts = np.fromiter((len(r) for r in rows), dtype=np.int64, count=len(rows))
    bad = ~np.isin(counts, allowed)
    if bad.any():
        j = int(np.argmax(bad))
        raise InputError(
            f"{p}, line {lines[j]}: {counts[j]} columns; expected {' or '.join(map(str, allowed))}"
        )
    try:
        data = np.array(rows, dtype=float)
    except ValueError:
        for r, ln in zip(rows, lines, strict=True):
            for tok in r:
                if not _numeric(tok):
                    raise InputError(f"{p}, line {ln}: '{tok}' is not a number") from None
        raise
    nonfinite = ~np.isfinite(data).all(axis=1)
    if nonfinite.any():
        j = int(np.argmax(nonfinite))
        raise InputError(f"{p}, line {lines[j]}: a value is NaN or infinite")
    return data, np.asarray(lines, dtype=np.int64)


def _numeric(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True
