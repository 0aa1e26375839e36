"""Writing matplotlib figures as PNG, atomically (the Agg backend: no display needed)."""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from imuslam.io.atomic import write_atomic  # noqa: E402


def save_figure(fig: Figure, path: str | Path) -> None:
    """Render ``fig`` to PNG in memory, write it atomically and close it."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    write_atomic(path, buf.getvalue())
