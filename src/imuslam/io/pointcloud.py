"""Point-cloud files: PCD (PCL's format, ascii and binary) and PLY read/write, KITTI ``.bin`` scans.

PCD v0.7 (pointclouds.org/documentation/tutorials/pcd_file_format): a text header (FIELDS, SIZE, TYPE,
COUNT, WIDTH, HEIGHT, POINTS, DATA) then the points. ``binary_compressed`` (LZF) is not read.
PLY (Turk 1994): binary little-endian vertices with float32 x, y, z and an optional intensity.
KITTI velodyne ``.bin``: float32 x, y, z, reflectance per point, no header.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.io.atomic import write_atomic

FloatArray = NDArray[np.float64]
_PCD_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4",
              ("I", 8): "<i8", ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8"}  # fmt: skip


def read_pcd(path: str | Path) -> dict[str, NDArray[np.generic]]:
    """Fields of a PCD file by name, each (N,) (or (N, count)); ``x``, ``y``, ``z`` are required."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise InputError(f"{p}: cannot read: {exc}") from exc
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise InputError(f"{p}: PCD header without a DATA line")
        line = raw[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key.upper()] = vals
        if key.upper() == "DATA":
            break
    for key in ("FIELDS", "SIZE", "TYPE", "POINTS"):
        if key not in header:
            raise InputError(f"{p}: PCD header has no {key} line")
    names = header["FIELDS"]
    count = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
    try:
        dts = [_PCD_TYPES[(t, int(s))] for t, s in zip(header["TYPE"], header["SIZE"], strict=True)]
    except (KeyError, ValueError) as exc:
        raise InputError(
            f"{p}: PCD field types {header['TYPE']} / sizes {header['SIZE']} not understood"
        ) from exc
    n = int(header["POINTS"][0])
    dtype = np.dtype([(f"{nm}_{i}" if names.count(nm) > 1 else nm, dt, (c,) if c > 1 else ())
                      for i, (nm, dt, c) in enumerate(zip(names, dts, count, strict=True))])  # fmt: skip
    mode = header["DATA"][0].lower()
    if mode == "binary":
        if len(raw) - pos < n * dtype.itemsize:
            raise InputError(
                f"{p}: {n} points announced, the data holds {(len(raw) - pos) // dtype.itemsize}"
            )
        arr = np.frombuffer(raw, dtype=dtype, count=n, offset=pos)
    elif mode == "ascii":
        numbers: NDArray[np.float64] = np.array(raw[pos:].split(), dtype=float)
        width = sum(count)
        if numbers.size != n * width:
            raise InputError(
                f"{p}: {n} points of {width} values announced, found {numbers.size} values"
            )
        arr = np.zeros(n, dtype=dtype)
        table = numbers.reshape(n, width)
        col = 0
        for nm, c in zip(dtype.names or (), count, strict=True):
            arr[nm] = table[:, col] if c == 1 else table[:, col : col + c]
            col += c
    else:
        raise InputError(f"{p}: PCD DATA {mode} is not supported (use ascii or binary)")
    out = {nm: np.asarray(arr[nm]) for nm in dtype.names or ()}
    for k in ("x", "y", "z"):
        if k not in out:
            raise InputError(f"{p}: PCD has no field '{k}' (fields: {' '.join(names)})")
    return out


def pcd_points(path: str | Path) -> FloatArray:
    """(N, 3) float64 x, y, z of a PCD file."""
    f = read_pcd(path)
    return np.column_stack([f["x"], f["y"], f["z"]]).astype(np.float64)


def write_pcd(path: str | Path, points: FloatArray, intensity: FloatArray | None = None) -> None:
    """Binary PCD with x, y, z (and intensity) as float32, atomically."""
    pts = np.asarray(points, dtype=np.float32)
    names = ["x", "y", "z"] + (["intensity"] if intensity is not None else [])
    cols = [pts[:, 0], pts[:, 1], pts[:, 2]] + (
        [np.asarray(intensity, np.float32)] if intensity is not None else []
    )
    arr = np.zeros(len(pts), dtype=[(n, "<f4") for n in names])
    for n, c in zip(names, cols, strict=True):
        arr[n] = c
    k = len(names)
    head = (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {' '.join(names)}\n"
            f"SIZE {' '.join(['4'] * k)}\nTYPE {' '.join(['F'] * k)}\nCOUNT {' '.join(['1'] * k)}\n"
            f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\nDATA binary\n")  # fmt: skip
    write_atomic(path, head.encode() + arr.tobytes())


def write_ply(path: str | Path, points: FloatArray, intensity: FloatArray | None = None) -> None:
    """Binary little-endian PLY with float32 x, y, z (and intensity), atomically."""
    pts = np.asarray(points, dtype=np.float32)
    names = ["x", "y", "z"] + (["intensity"] if intensity is not None else [])
    arr = np.zeros(len(pts), dtype=[(n, "<f4") for n in names])
    arr["x"], arr["y"], arr["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if intensity is not None:
        arr["intensity"] = intensity
    props = "".join(f"property float {n}\n" for n in names)
    head = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\n{props}end_header\n"
    write_atomic(path, head.encode() + arr.tobytes())


def read_ply(path: str | Path) -> FloatArray:
    """(N, 3) x, y, z of a binary little-endian PLY whose vertices are all float32 properties."""
    p = Path(path)
    raw = p.read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply") or end < 0:
        raise InputError(f"{p}: not a PLY file")
    lines = raw[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise InputError(f"{p}: only binary little-endian PLY is read")
    n = next(int(ln.split()[2]) for ln in lines if ln.startswith("element vertex"))
    props = [ln.split()[2] for ln in lines if ln.startswith("property float")]
    arr = np.frombuffer(
        raw, dtype=[(q, "<f4") for q in props], count=n, offset=end + len(b"end_header\n")
    )
    return np.column_stack([arr["x"], arr["y"], arr["z"]]).astype(np.float64)


def read_kitti_bin(path: str | Path) -> tuple[FloatArray, FloatArray]:
    """Points (N, 3) and reflectance (N,) of a KITTI velodyne ``.bin`` scan."""
    p = Path(path)
    raw = p.read_bytes()
    if len(raw) % 16:
        raise InputError(f"{p}: {len(raw)} bytes is not a whole number of 16-byte KITTI points")
    a = np.frombuffer(raw, dtype="<f4").reshape(-1, 4)
    return a[:, :3].astype(np.float64), a[:, 3].astype(np.float64)
