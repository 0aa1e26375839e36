"""Start-up of the command line: the help imports no heavy library, and the lazy command table matches
the commands it stands for."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import imuslam
from imuslam.cli import COMMANDS, load_command

HEAVY = ("numpy", "numba", "scipy", "matplotlib", "rosbags", "cv2", "dask", "gtsam")
CLI_DIR = Path(imuslam.__file__).parent / "cli"


def _modules_after(argv: list[str]) -> set[str]:
    """Top-level packages among HEAVY imported by ``imuslam <argv>`` in a fresh process."""
    code = (
        "import sys\n"
        f"sys.argv = ['imuslam', *{argv!r}]\n"
        "from imuslam.cli import main\n"
        "try:\n    main()\nexcept SystemExit:\n    pass\n"
        f"print('MODULES=' + ','.join(m for m in {HEAVY!r} if m in sys.modules), file=sys.stderr)\n"
    )
    env = dict(os.environ, PYTHONPATH=str(Path(imuslam.__file__).parents[1]))
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    line = [x for x in r.stderr.splitlines() if x.startswith("MODULES=")]
    assert line, r.stderr
    return {m for m in line[-1].removeprefix("MODULES=").split(",") if m}


@pytest.mark.parametrize("argv", [["--help"]] + [[c, "--help"] for c in COMMANDS])
def test_help_loads_no_heavy_library(argv: list[str]) -> None:
    """Every command's module imports only typer and its own thin body (not even numpy)."""
    assert _modules_after(argv) == set()


def test_eval_without_plots_loads_neither_scipy_nor_numba(tmp_path: Path) -> None:
    """``imuslam eval --no-plots`` (SE(3), Sim(3)) needs numpy only: no scipy, numba, matplotlib."""
    t = 1.0 + 0.1 * np.arange(50)
    rows = np.column_stack([t, np.cos(t), np.sin(t), 0.1 * t, np.zeros((50, 3)), np.ones(50)])
    for name, r in (("gt.tum", rows), ("est.tum", rows + [0, 0.01, 0, 0, 0, 0, 0, 0])):
        np.savetxt(tmp_path / name, r, fmt="%.9f")
    argv = ["eval", str(tmp_path / "gt.tum"), str(tmp_path / "est.tum"), "--align", "sim3",
            "--no-plots", "--out", str(tmp_path / "out")]  # fmt: skip
    assert _modules_after(argv) == {"numpy"}
    assert (tmp_path / "out" / "metrics.json").is_file()


def test_every_command_module_is_listed() -> None:
    with_register = {
        p.stem for p in CLI_DIR.glob("*.py") if re.search(r"^def register\(", p.read_text(), re.M)
    }
    assert with_register == {mod for mod, _ in COMMANDS.values()}


@pytest.mark.parametrize("name", list(COMMANDS))
def test_listed_help_is_the_commands_own(name: str) -> None:
    cmd = load_command(name)
    assert cmd.name == name
    first_paragraph = " ".join((cmd.help or "").split("\n\n")[0].split())
    assert " ".join(COMMANDS[name][1].split()) == first_paragraph


def test_simulate_scenario_choices_match_the_simulator() -> None:
    from imuslam.cli.simulate import Scenario
    from imuslam.sim.scenario import SCENARIOS

    assert tuple(s.value for s in Scenario) == SCENARIOS
