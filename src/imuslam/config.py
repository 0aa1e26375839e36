"""Configuration: nested pydantic models loaded from YAML whose keys equal the field names.

Each estimator defines its own model beside its code; this module loads and writes them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from imuslam.errors import InputError
from imuslam.io.atomic import write_atomic
from imuslam.io.yamlfile import read_yaml

ModelT = TypeVar("ModelT", bound=BaseModel)


def load_config(path: str | Path, model: type[ModelT]) -> ModelT:
    """Read ``path`` (YAML) into ``model``; a bad key or value is an InputError naming the field."""
    p = Path(path)
    data = read_yaml(p, f"a mapping of {model.__name__} fields", empty={})
    unknown = _unknown_keys(data, model)
    if unknown:
        raise InputError(
            f"{p}: unknown key(s) {', '.join(unknown)}; {model.__name__} has "
            f"{', '.join(model.model_fields)}"
        )
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise InputError(f"{p}: {describe_validation_error(exc)}") from None


def describe_validation_error(exc: ValidationError) -> str:
    """One line for a configuration's validation errors: per error the field and what was expected
    (a check across fields, which has no field, by its message alone)."""
    return "; ".join(
        f"field '{'.'.join(map(str, e['loc']))}': {str(e['msg']).removeprefix('Value error, ')} "
        f"(got {e.get('input')!r:.40})"
        if e["loc"]
        else str(e["msg"]).removeprefix("Value error, ")
        for e in exc.errors()
    )


def _unknown_keys(data: dict[str, Any], model: type[BaseModel], prefix: str = "") -> list[str]:
    """Keys of ``data`` that are not fields of ``model`` (nested models checked too), dotted."""
    out: list[str] = []
    for k, v in data.items():
        f = model.model_fields.get(str(k))
        if f is None:
            out.append(f"'{prefix}{k}'")
        elif (
            isinstance(v, dict)
            and isinstance(f.annotation, type)
            and issubclass(f.annotation, BaseModel)
        ):
            out += _unknown_keys(v, f.annotation, f"{prefix}{k}.")
    return out


def dump_config(model: BaseModel, path: str | Path) -> None:
    """Write the effective configuration beside a result, atomically."""
    write_atomic(path, yaml.safe_dump(model.model_dump(mode="json"), sort_keys=False))
