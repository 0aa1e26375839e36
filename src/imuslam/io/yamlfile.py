"""The one reader of every YAML file a user gives (configurations, studies, calibrations, camchains,
Kalibr noise files): bytes that are not text, a YAML syntax error or a top level that is not a mapping
become one :class:`~imuslam.errors.InputError` line naming the file, the line where YAML gives it, and
what the file should hold.

    data = read_yaml(path, "a LioConfig (keys = field names)")
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from imuslam.errors import InputError
from imuslam.io.text import read_text


def read_yaml(
    path: str | Path, what: str, *, empty: dict[str, Any] | None = None
) -> dict[str, Any]:
    """The mapping at the top of the YAML file ``path``; ``what`` says what it should hold (it ends
    every message). An empty file (or one of comments) gives ``empty`` when one is given (a
    configuration that changes no default), else an InputError.

    OpenCV's ``%YAML:1.0`` first line (EuRoC's ``sensor.yaml``) is skipped: PyYAML reads only the
    ``%YAML 1.x`` form."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file; expected {what}")
    text = read_text(p)  # not text, UTF-16 without BOM, NUL bytes: InputError naming the line
    skipped = 0
    if text.startswith("%YAML:"):
        text = text.split("\n", 1)[1] if "\n" in text else ""
        skipped = 1
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        at = f", line {mark.line + 1 + skipped}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputError(f"{p}{at}: not valid YAML ({problem}); expected {what}") from None
    except RecursionError:  # "[[[[..." thousands deep
        raise InputError(f"{p}: YAML nested too deeply; expected {what}") from None
    if data is None:
        if empty is not None:
            return dict(empty)
        raise InputError(f"{p}: empty; expected {what}")
    if not isinstance(data, dict):
        kind = {
            str: "a string",
            list: "a list",
            int: "a number",
            float: "a number",
            bool: "a boolean",
        }
        got = kind.get(type(data), type(data).__name__)
        raise InputError(f"{p}: the file holds {got}, not a mapping of keys; expected {what}")
    bad = [k for k in data if not isinstance(k, str)]
    if bad:
        raise InputError(f"{p}: key {bad[0]!r} is not a name; expected {what}")
    return data
