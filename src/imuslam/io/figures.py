"""Writing matplotlib figures as PNG, atomically.

Figures are built as ``matplotlib.figure.Figure`` objects (no pyplot: no global state, no backend to
choose, nothing to close) and rendered here by the Agg canvas that ``savefig`` attaches.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import TYPE_CHECKING

from imuslam.io.atomic import write_atomic

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def save_figure(fig: Figure, path: str | Path) -> None:
    """Render ``fig`` to PNG in memory and write it atomically."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    write_atomic(path, buf.getvalue())
