"""Configuration: nested pydantic models loaded from YAML whose keys equal the field names.

Each estimator defines its own model beside its code; this module loads and writes them.
"""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from imuslam.errors import InputError
from imuslam.io.atomic import write_atomic

ModelT = TypeVar("ModelT", bound=BaseModel)


def load_config(path: str | Path, model: type[ModelT]) -> ModelT:
    """Read ``path`` (YAML) into ``model``; a bad key or value is an InputError naming the field."""
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text()) or {}
    except OSError as exc:
        raise InputError(f"{p}: cannot read configuration: {exc}") from exc
    except yaml.YAMLError as exc:
        raise InputError(f"{p}: not valid YAML: {exc}") from exc
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise InputError(f"{p}: invalid configuration:\n{exc}") from exc


def dump_config(model: BaseModel, path: str | Path) -> None:
    """Write the effective configuration beside a result, atomically."""
    write_atomic(path, yaml.safe_dump(model.model_dump(mode="json"), sort_keys=False))
