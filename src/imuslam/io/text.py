"""Reading numeric text tables with errors that name the file and line."""

from __future__ import annotations

import codecs
import os
import pickle
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import cast

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError

INT64_MAX = np.iinfo(np.int64).max
PREFETCH_MIN_BYTES = 1 << 20  # below about 1 MB a fork costs more than the parse it overlaps

_TableKey = tuple[str, tuple[int, ...], str, bool | None]
_Parsed = tuple[NDArray[np.float64], NDArray[np.int64]]


class _Prefetch:
    """Tables parsed by a forked child: its pid, the read end of its pipe, the keys it parses."""

    def __init__(self, pid: int, fd: int, keys: list[_TableKey]) -> None:
        self.pid, self.fd, self.keys = pid, fd, keys
        self.results: dict[_TableKey, tuple[str, object]] | None = None

    def collect(self) -> dict[_TableKey, tuple[str, object]]:
        if self.results is None:
            with os.fdopen(self.fd, "rb") as fh:
                raw = fh.read()
            os.waitpid(self.pid, 0)
            try:
                got = pickle.loads(raw)
            except Exception:  # the child died before writing: parse here
                got = {}
            self.results = {k: got.get(k, ("again", None)) for k in self.keys}
        return self.results


_PENDING: dict[_TableKey, _Prefetch] = {}


def cancel_prefetch() -> None:
    """Stop and reap every child whose tables were not read (a command that failed before reading)."""
    jobs = {id(j): j for j in _PENDING.values()}
    _PENDING.clear()
    for job in jobs.values():
        if job.results is None:
            try:
                os.kill(job.pid, 9)
            except OSError:
                pass
            os.close(job.fd)
            os.waitpid(job.pid, 0)
            job.results = {}


def _key(
    path: str | Path, allowed: tuple[int, ...], comment: str, skip_header: bool | None
) -> _TableKey:
    return (os.path.abspath(path), allowed, comment, skip_header)


def prefetch_tables(
    paths: Sequence[str | Path],
    n_cols: int | tuple[int, ...],
    comment: str = "#%",
    skip_header: bool | None = None,
) -> bool:
    """Start parsing ``paths`` in a forked child while this process goes on (its imports, say), so
    that two cores share the work; a later :func:`read_table` of the same path and arguments takes
    the child's result (or its InputError, with the same message). Done only where it can pay: a
    Linux fork, two or more usable cores and at least ``PREFETCH_MIN_BYTES`` of files; otherwise (and
    whenever the child fails) the files are parsed in place, as without this call. Returns whether a
    child was started."""
    allowed = (n_cols,) if isinstance(n_cols, int) else tuple(n_cols)
    cancel_prefetch()
    if not sys.platform.startswith("linux") or len(os.sched_getaffinity(0)) < 2:
        return False  # fork is unsafe with macOS's system frameworks; Windows has none
    try:
        size = sum(os.stat(p).st_size for p in paths)
    except OSError:  # the reader names what is missing
        return False
    if size < PREFETCH_MIN_BYTES:
        return False
    keys = [_key(p, allowed, comment, skip_header) for p in paths]
    r, w = os.pipe()
    try:
        pid = os.fork()
    except OSError:
        os.close(r)
        os.close(w)
        return False
    if pid == 0:  # the child: parse, send, leave without running the parent's exit handlers
        code = 1
        try:
            os.close(r)
            out: dict[_TableKey, tuple[str, object]] = {}
            for k, p in zip(keys, paths, strict=True):
                try:
                    out[k] = ("ok", _read_table_now(Path(p), allowed, comment, skip_header))
                except InputError as exc:
                    out[k] = ("error", str(exc))
            with os.fdopen(w, "wb") as fh:
                pickle.dump(out, fh, protocol=pickle.HIGHEST_PROTOCOL)
            code = 0
        finally:
            os._exit(code)
    os.close(w)
    job = _Prefetch(pid, r, keys)
    for k in keys:
        _PENDING[k] = job
    return True


def read_text(path: str | Path) -> str:
    """The text of ``path``: UTF-8 (a BOM allowed) or UTF-16 with its BOM (as Windows tools write it).

    A folder, an unreadable file, bytes that are not text in those encodings, or NUL characters are an
    InputError naming the file (and the line of the first NUL)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except IsADirectoryError:
        raise InputError(f"{p}: a folder; expected a file") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror})") from None
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        enc = "utf-16"
    elif raw.startswith(codecs.BOM_UTF8):
        enc = "utf-8-sig"
    else:
        enc = "utf-8"
    try:
        text = raw.decode(enc)
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise InputError(
            f"{p}, line {line}: not a text file (byte {exc.start} is not valid {enc}); "
            "expected UTF-8 or UTF-16 text"
        ) from None
    nul = text.find("\x00")
    if nul >= 0:
        line = text.count("\n", 0, nul) + 1
        raise InputError(f"{p}, line {line}: not a text file (a NUL character); expected text")
    return text


def read_table(
    path: str | Path,
    n_cols: int | tuple[int, ...],
    comment: str = "#%",
    skip_header: bool | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Numeric rows (N, C) of a whitespace- or comma-separated file and their 1-based line numbers.

    n_cols: the accepted column count(s); every row must have the same count, one of these; a row
    with another is an InputError naming its line. Blank lines and lines starting with a ``comment``
    character are skipped; a first line that is not numeric is taken as a header when ``skip_header``
    is None.
    """
    p = Path(path)
    allowed = (n_cols,) if isinstance(n_cols, int) else tuple(n_cols)
    job = _PENDING.pop(_key(p, allowed, comment, skip_header), None) if _PENDING else None
    if job is not None:
        kind, value = job.collect()[_key(p, allowed, comment, skip_header)]
        if kind == "ok":
            return cast("_Parsed", value)
        if kind == "error":
            raise InputError(str(value))
    return _read_table_now(p, allowed, comment, skip_header)


def _read_table_now(
    p: Path, allowed: tuple[int, ...], comment: str, skip_header: bool | None
) -> _Parsed:
    text = read_text(p)
    fast = _parse_plain(text, allowed, comment, skip_header)
    if fast is not None:
        return fast
    data, lines, _ = _parse(p, allowed, comment, skip_header, text)
    return data, lines


def _parse_plain(
    text: str, allowed: tuple[int, ...], comment: str, skip_header: bool | None
) -> tuple[NDArray[np.float64], NDArray[np.int64]] | None:
    """The common case in numpy's C parser: whitespace-separated numbers on every line, no comment,
    no header, no blank line, finite values, an accepted column count. None when anything else is
    there (the line-by-line parser then finds it and names the line)."""
    if skip_header or "," in text or any(c in text for c in comment):
        return None
    lines = text.splitlines()
    if not lines or not lines[0].split() or not _numeric(lines[0].split()[0]):
        return None
    try:
        data = np.loadtxt(lines, dtype=np.float64, ndmin=2, comments=None)
    except ValueError:
        return None
    if data.shape[0] != len(lines) or data.shape[1] not in allowed:
        return None
    if not np.isfinite(data).all():
        return None
    return data, np.arange(1, len(lines) + 1, dtype=np.int64)


def read_table_ns(
    path: str | Path, n_cols: int | tuple[int, ...], comment: str = "#%"
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """:func:`read_table` whose first column is also returned exactly as int64 nanoseconds (stamps
    that float64 would round): ``(data, lines, t_ns)``; a stamp beyond int64 is an InputError."""
    p = Path(path)
    data, lines, rows = _parse(p, n_cols, comment, None)
    return data, lines, _int_column([r[0] for r in rows], data[:, 0], lines, p)


def _parse(
    p: Path,
    n_cols: int | tuple[int, ...],
    comment: str,
    skip_header: bool | None,
    text: str | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64], list[list[str]]]:
    text = read_text(p) if text is None else text
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
    ragged = counts != counts[0]
    if ragged.any():
        j = int(np.argmax(ragged))
        raise InputError(
            f"{p}, line {lines[j]}: {counts[j]} columns; the rows before it have {counts[0]}"
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
    return data, np.asarray(lines, dtype=np.int64), rows


def _int_column(
    toks: list[str], values: NDArray[np.float64], lines: NDArray[np.int64], p: Path
) -> NDArray[np.int64]:
    """Exact int64 of integer tokens (a float token such as 1.4e18 is rounded); beyond int64 is an error."""
    big = np.abs(values) >= INT64_MAX
    if big.any():
        j = int(np.argmax(big))
        raise InputError(
            f"{p}, line {int(lines[j])}: time stamp {toks[j]} is beyond the int64 range of "
            "nanosecond stamps (up to 9.2e18 ns, the year 2262)"
        )
    try:
        return np.array(toks).astype(np.int64)
    except (ValueError, OverflowError):
        pass
    out = np.round(values).astype(np.int64)
    for j, tok in enumerate(toks):  # only when a token is not a plain integer: exact where it is
        try:
            out[j] = int(tok)
        except ValueError:
            continue
        except OverflowError:
            raise InputError(
                f"{p}, line {int(lines[j])}: time stamp {tok} is beyond int64"
            ) from None
    return out


def _numeric(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True
