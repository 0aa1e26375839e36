"""No module of the package uses another module's private (``_name``) names, nor pyplot.

A leading underscore says "this module's own": a second module that imports it (``from imuslam.x import
_y``), or reaches it through a module it imported (``x._y``), couples itself to an implementation detail
and breaks silently when it changes. The layers contract (``lint-imports``) cannot see this; this scan does.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _resolve(node: ast.ImportFrom, here: str, is_pkg: bool) -> str:
    if not node.level:
        return node.module or ""
    base = here.split(".") if is_pkg else here.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def private_uses(path: Path, here: str | None = None) -> list[str]:
    """Each use in ``path`` (module ``here``, by default from its place under src/) of a private name
    of another imuslam module, as ``line: what``."""
    here = here or _module_name(path)
    tree = ast.parse(path.read_text(), str(path))
    found: list[str] = []
    modules: dict[str, str] = {}  # local name -> imuslam module it is bound to
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            src = _resolve(node, here, path.name == "__init__.py")
            if not src.startswith("imuslam") or src == here:
                continue
            for a in node.names:
                if _private(a.name) or any(_private(p) for p in src.split(".")):
                    found.append(f"{node.lineno}: from {src} import {a.name}")
                elif (SRC / Path(*src.split("."), f"{a.name}.py")).exists() or (
                    SRC / Path(*src.split("."), a.name)
                ).is_dir():
                    modules[a.asname or a.name] = f"{src}.{a.name}"
        elif isinstance(node, ast.Import):
            for a in node.names:
                if not a.name.startswith("imuslam"):
                    continue
                if any(_private(p) for p in a.name.split(".")):
                    found.append(f"{node.lineno}: import {a.name}")
                if a.asname:
                    modules[a.asname] = a.name
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in modules
            and modules[node.value.id] != here
            and _private(node.attr)
        ):
            found.append(f"{node.lineno}: {modules[node.value.id]}.{node.attr}")
    return found


def test_no_module_uses_another_modules_private_names() -> None:
    files = sorted(SRC.rglob("*.py"))
    assert len(files) > 50  # the scan sees the package
    bad = {str(p.relative_to(SRC)): u for p in files if (u := private_uses(p))}
    assert not bad, f"private names used across modules: {bad}"


def test_the_scan_finds_each_kind_of_private_use(tmp_path: Path) -> None:
    """The check can fail: a module with each kind of use is reported, line by line."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "from imuslam.vio.pipeline import _hidden\n"
        "from imuslam.vio import pipeline\n"
        "from . import pipeline as pl\n"
        "import imuslam.io.results as res\n"
        "x = pipeline._other + pl._third + res._umask()\n"
        "y = pipeline.public + pl.__name__\n"
    )
    uses = private_uses(probe, here="imuslam.vio.probe")
    assert sorted(uses) == [
        "1: from imuslam.vio.pipeline import _hidden",
        "5: imuslam.io.results._umask",
        "5: imuslam.vio.pipeline._other",
        "5: imuslam.vio.pipeline._third",
    ]


def test_matplotlib_only_through_figure() -> None:
    """No pyplot (global state, a backend chosen at import) anywhere in the package."""
    bad = []
    for p in sorted(SRC.rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text(), str(p))):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [f"{node.module}.{a.name}" for a in node.names]
                if isinstance(node, ast.ImportFrom) and node.module
                else []
            )
            bad += [f"{p.relative_to(SRC)}:{node.lineno}" for n in names if "pyplot" in n]
    assert not bad, f"pyplot imported: {bad}"
