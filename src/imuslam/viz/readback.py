"""A recording read back with rerun's own reader (``rerun.chunk.RrdReader``): what each entity holds,
for the tests and for a user checking a file without the viewer."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray


@dataclass
class EntityRows:
    """An entity's rows on the timelines (``rows``, their timelines, each column's values in row order,
    sorted by ``sensor_time`` when the entity has it, stamps as int64 ns) and its static rows
    (``static_rows``, ``static`` columns)."""

    rows: int = 0
    timelines: set[str] = field(default_factory=set)
    columns: dict[str, list[Any]] = field(default_factory=dict)
    static_rows: int = 0
    static: dict[str, list[Any]] = field(default_factory=dict)

    def times_ns(self, timeline: str = "sensor_time") -> NDArray[np.int64]:
        return np.array(self.columns.get(timeline, []), dtype=np.int64)

    def array(self, column: str) -> NDArray[np.float64]:
        """A column as floats, one row per entry (rows of a single instance flattened)."""
        vals = [v[0] if isinstance(v, list) and len(v) == 1 else v for v in self.columns[column]]
        return np.array(vals, dtype=np.float64)


def load(path: str | Path) -> dict[str, EntityRows]:
    """Every entity of the first recording in the ``.rrd`` file at ``path``, by entity path."""
    from rerun.chunk import RrdReader

    out: dict[str, EntityRows] = {}
    for chunk in RrdReader(Path(path)).stream():
        e = out.setdefault(chunk.entity_path, EntityRows())
        rb = chunk.to_record_batch()
        if chunk.is_static:
            e.static_rows += chunk.num_rows
            cols = e.static
        else:
            e.rows += chunk.num_rows
            e.timelines.update(chunk.timeline_names)
            cols = e.columns
        for name in rb.schema.names:
            if name.startswith("rerun.controls"):
                continue
            col = rb.column(name)
            vals = col.cast("int64").to_pylist() if name in e.timelines else col.to_pylist()
            cols.setdefault(name, []).extend(vals)
    for e in out.values():  # chunks need not come in time order
        t = e.columns.get("sensor_time")
        if t is not None and len(t) == e.rows:
            order = np.argsort(np.array(t, dtype=np.int64), kind="stable")
            e.columns = {k: [v[i] for i in order] if len(v) == e.rows else v
                         for k, v in e.columns.items()}  # fmt: skip
    return out
