"""Results on disk all or nothing: an output path is checked before any work, and a command's set of
outputs is written into a temporary sibling that replaces the target only when everything succeeded.

    check_out_dir(out, "folder")           # before reading anything: fails fast on a bad --out
    ...                                     # the work
    with results_folder(out) as tmp:        # every output written into tmp
        save(tmp / "a.yaml"); plot(tmp / "b.png")
    # on success tmp's entries are in out; on any error (an exception, a full disk) nothing is left

A file on its own (``correct --out x.mcap``) goes through :func:`results_file` the same way.

The user's files are never lost:
- :func:`check_not_input` refuses, before any work, an output that is one of the command's inputs,
  holds one, or lies inside an input folder;
- an existing folder keeps every file the command does not write, and a file it does write replaces
  only a file that an earlier imuslam run wrote there (listed in the folder's :data:`MANIFEST`): a
  file of the same name that imuslam did not write stops the run with nothing written;
- a single output file (:func:`results_file`) is never written over an existing one.
"""

from __future__ import annotations

import errno
import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from imuslam.errors import InputError
from imuslam.io.atomic import atomic_path, write_atomic

if TYPE_CHECKING:
    from imuslam.interfaces.trajectory import Trajectory

OutKind = Literal["folder", "file", "any"]

#: The list of the entries that imuslam wrote into a results folder (those a later run may replace).
MANIFEST = ".imuslam-results.json"

# Errors of the output location itself: reported as bad input (the --out option), exit 2.
_OUT_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG}


def _first_existing(p: Path) -> Path:
    a = p
    while not a.exists() and a != a.parent:
        a = a.parent
    return a


def check_out_dir(path: str | Path, kind: OutKind = "folder", option: str = "--out") -> None:
    """Raise an InputError naming ``option`` unless ``path`` can receive a ``kind`` output.

    folder: absent, or an existing writable folder; file: absent or an existing file, in a folder that
    can be created and written; any: either. A path under an existing file is always an error.
    """
    p = Path(path).absolute()
    if p.is_symlink() and not p.exists():
        raise InputError(
            f"{option} {path}: a symbolic link to nothing; expected a folder or a new name"
        )
    if p.exists():
        if kind == "folder" and not p.is_dir():
            raise InputError(
                f"{option} {path}: an existing file; expected a folder (new or existing)"
            )
        if kind == "file" and p.is_dir():
            raise InputError(f"{option} {path}: an existing folder; expected a file name")
        if p.is_dir() and not os.access(p, os.W_OK | os.X_OK):
            raise InputError(f"{option} {path}: the folder is not writable")
    a = _first_existing(p.parent)
    if not a.is_dir():
        raise InputError(f"{option} {path}: {a} is a file, so nothing can be created under it")
    if not os.access(a, os.W_OK | os.X_OK):
        raise InputError(f"{option} {path}: {a} is not writable")


def check_not_input(
    out: str | Path,
    inputs: Iterable[tuple[str, str | Path | None]],
    option: str = "--out",
) -> None:
    """Raise an InputError naming ``option`` if ``out`` is one of ``inputs``, holds one, or lies inside
    an input folder (symbolic links followed). ``inputs`` are ``(what, path)`` pairs, e.g.
    ``("the log", log_path)``; a None path or one that does not exist is skipped."""
    o = Path(out).resolve()
    for what, path in inputs:
        if path is None or not os.path.lexists(path):
            continue
        i = Path(path).resolve()
        if o == i:
            raise InputError(f"{option} {out}: is {what} {path}; choose a new results folder")
        if o in i.parents:
            raise InputError(
                f"{option} {out}: holds {what} {path}; choose a folder that does not contain the input"
            )
        if i.is_dir() and i in o.parents:
            raise InputError(
                f"{option} {out}: lies inside {what} {path}; choose a folder outside the input"
            )


def _read_manifest(folder: Path) -> set[str]:
    try:
        data = json.loads((folder / MANIFEST).read_text())
        return {str(x) for x in data.get("entries", [])} if isinstance(data, dict) else set()
    except (OSError, ValueError):
        return set()


def _write_manifest(folder: Path, entries: Iterable[str]) -> None:
    text = json.dumps({"written_by": "imuslam", "entries": sorted(set(entries))}, indent=1)
    write_atomic(folder / MANIFEST, text + "\n")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def _parents(p: Path) -> Iterator[None]:
    """Create the missing parents of ``p``; remove the ones created here if the block fails."""
    missing: list[Path] = []
    a = p.parent
    while not a.exists():
        missing.append(a)
        a = a.parent
    for d in reversed(missing):
        d.mkdir()
    try:
        yield
    except BaseException:
        for d in missing:  # deepest first; only if still empty
            try:
                d.rmdir()
            except OSError:
                break
        raise


def _as_input_error(exc: OSError, out: Path, option: str) -> InputError | OSError:
    if exc.errno in _OUT_ERRNOS:
        return InputError(f"{option} {out}: cannot write ({exc.strerror}); nothing was written")
    return exc


def _move_into(src: Path, dst: Path) -> None:
    """Move every entry of folder ``src`` into the existing folder ``dst``, replacing same names (a
    replaced folder goes into ``src``, removed with it). Each move is a rename: no space needed."""
    entries = sorted(e for e in src.iterdir() if e.name != MANIFEST)
    ours = _read_manifest(dst)
    foreign = [e.name for e in entries if os.path.lexists(dst / e.name) and e.name not in ours]
    if foreign:
        raise FileExistsError(
            errno.EEXIST,
            f"{', '.join(foreign)} already there and not written by imuslam; nothing was written "
            "(move it away or choose another results folder)",
            str(dst),
        )
    _write_manifest(dst, ours | {e.name for e in entries})
    trash = Path(tempfile.mkdtemp(dir=src, prefix=".replaced-"))
    for e in entries:
        target = dst / e.name
        if target.is_dir() and not target.is_symlink():
            os.replace(target, trash / e.name)
        os.replace(e, target)


@contextmanager
def results_folder(out: str | Path, option: str = "--out") -> Iterator[Path]:
    """Yield an empty temporary folder; on success its entries land in ``out`` (created if absent),
    on any error it is removed and ``out`` is as it was.

    An absent ``out`` is created in one rename. An existing ``out`` keeps the files it has that the
    command does not write (``--out .`` is safe); those it writes are replaced one rename each, and only
    where an earlier imuslam run wrote them (:data:`MANIFEST`): a file of the user's with the same name
    stops the run before anything is moved.
    """
    o = Path(out)
    check_out_dir(o, "folder", option)
    p = o.absolute()
    existed = p.is_dir()
    with _parents(p):
        base = p if existed else p.parent
        tmp = Path(tempfile.mkdtemp(dir=base, prefix=f".{p.name or 'out'}.partial-"))
        try:
            try:
                yield tmp
                if existed:
                    _move_into(tmp, p)
                else:
                    _write_manifest(tmp, (e.name for e in tmp.iterdir()))
                    os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp made it private
                    try:
                        os.rename(tmp, p)
                    except OSError as exc:  # another run created ``out`` meanwhile: add to it
                        if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST) or not p.is_dir():
                            raise
                        _move_into(tmp, p)
            except FileExistsError as exc:
                raise InputError(f"{option} {out}: {exc.strerror}") from None
            except OSError as exc:
                raise _as_input_error(exc, o, option) from exc
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


@contextmanager
def results_file(out: str | Path, option: str = "--out") -> Iterator[Path]:
    """:func:`imuslam.io.atomic.atomic_path` after the preflight of ``out``: a temporary path beside it
    that becomes ``out`` (a file, or a folder bag written there) on success and is removed on any
    error, with the parents it had to create. An existing ``out`` is never written over."""
    o = Path(out)
    check_out_dir(o, "any", option)
    p = o.absolute()
    if os.path.lexists(p):
        raise InputError(f"{option} {out}: exists; choose a new name (nothing is written over)")
    with _parents(p):
        try:
            with atomic_path(p) as tmp:
                yield tmp
        except FileExistsError:
            raise InputError(
                f"{option} {out}: appeared while the command ran; nothing was written over it"
            ) from None
        except OSError as exc:
            raise _as_input_error(exc, o, option) from exc


def json_safe(x: Any) -> Any:
    """NaN and infinities as null (JSON has no Infinity); numpy scalars and arrays as plain values;
    a pydantic model or an object with ``to_dict`` as its dictionary."""
    import numpy as np

    if hasattr(x, "model_dump"):
        return json_safe(x.model_dump(mode="json"))
    if hasattr(x, "to_dict"):
        return json_safe(x.to_dict())
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    if isinstance(x, np.ndarray):
        return json_safe(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, Path):
        return str(x)
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def write_json(path: Path, data: Any) -> None:
    """Standard JSON (a non-finite number is written as null), atomically."""
    text = json.dumps(json_safe(data), indent=2, default=float, allow_nan=False)
    write_atomic(path, text + "\n")


def write_results(
    out: str | Path,
    *,
    config: Any,
    metrics: Any,
    trajectories: dict[str, Trajectory] | None = None,
    extra: Callable[[Path], Any] | None = None,
    option: str = "--out",
) -> Path:
    """THE results folder of a command, all or nothing (:func:`results_folder`).

    Writes ``config.yaml`` (the effective configuration: a pydantic model or a mapping),
    ``metrics.json``, one ``<name>.tum`` per trajectory (stamps with 9 decimals, exact from ``t_ns``),
    then calls ``extra(folder)`` for what is the command's own (plots, reports, maps).
    """
    import yaml

    from imuslam.io.trajectory import write_tum

    with results_folder(out, option) as tmp:
        cfg = json_safe(config)
        write_atomic(tmp / "config.yaml", yaml.safe_dump(cfg, sort_keys=False))
        write_json(tmp / "metrics.json", metrics)
        for name, traj in (trajectories or {}).items():
            write_tum(traj, tmp / f"{name}.tum")
        if extra is not None:
            extra(tmp)
    return Path(out)
