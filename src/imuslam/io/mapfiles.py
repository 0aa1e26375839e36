"""Occupancy maps as ROS map_server files: an 8-bit PGM (P5) and its YAML (image, resolution, origin,
negate, occupied_thresh, free_thresh), as ``map_server``'s ``map_saver`` writes them: occupied 0, free 254,
unknown 205, the first image row the top (largest y) of the map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.io.atomic import write_atomic

OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196


def occupancy_image(prob: NDArray[np.floating], known: NDArray[np.bool_]) -> NDArray[np.uint8]:
    """(H, W) probability (rows = increasing y) -> map_saver's trinary image (rows = decreasing y)."""
    img = np.full(prob.shape, 205, np.uint8)
    img[known & (prob >= OCCUPIED_THRESH)] = 0
    img[known & (prob <= FREE_THRESH)] = 254
    return np.ascontiguousarray(img[::-1])


def write_map_server(
    out_dir: str | Path, prob: NDArray[np.floating], known: NDArray[np.bool_], x0: float, y0: float,
    resolution: float, name: str = "map",
) -> tuple[Path, Path]:  # fmt: skip
    """Write ``name.pgm`` and ``name.yaml``; (x0, y0) is the lower-left corner of cell (0, 0), m."""
    out = Path(out_dir)
    img = occupancy_image(prob, known)
    h, w = img.shape
    write_atomic(out / f"{name}.pgm", f"P5\n{w} {h}\n255\n".encode() + img.tobytes())
    yaml = (
        f"image: {name}.pgm\nresolution: {resolution:.6g}\norigin: [{x0:.6f}, {y0:.6f}, 0.0]\n"
        f"negate: 0\noccupied_thresh: {OCCUPIED_THRESH}\nfree_thresh: {FREE_THRESH}\n"
    )
    write_atomic(out / f"{name}.yaml", yaml)
    return out / f"{name}.pgm", out / f"{name}.yaml"


def read_map_server(yaml_path: str | Path) -> tuple[NDArray[np.uint8], float, tuple[float, float]]:
    """The image (rows = decreasing y), resolution and origin (x, y) of a map_server map."""
    p = Path(yaml_path)
    import yaml

    try:
        meta = yaml.safe_load(p.read_text())
        data = (p.parent / meta["image"]).read_bytes()
    except (OSError, KeyError, TypeError) as exc:
        raise InputError(f"{p}: not a map_server YAML ({exc})") from None
    parts = data.split(maxsplit=4)
    if parts[0] != b"P5":
        raise InputError(f"{p.parent / meta['image']}: not a binary PGM (P5)")
    w, h = int(parts[1]), int(parts[2])
    img = np.frombuffer(parts[4][: w * h], np.uint8).reshape(h, w)
    return img, float(meta["resolution"]), (float(meta["origin"][0]), float(meta["origin"][1]))
