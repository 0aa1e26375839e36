"""``imuslam allan``: Allan deviation of a static log, noise terms and a Kalibr imu.yaml."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from imuslam.cli import validate
from imuslam.cli.common import (
    FORMAT_HELP,
    AccelUnitChoice,
    GyroUnitChoice,
    ImuFormatChoice,
    console,
    friendly_errors,
    load_log,
    print_warnings,
    table,
    value,
)

if TYPE_CHECKING:  # numba, matplotlib and yaml load when the command runs
    from matplotlib.figure import Figure

    from imuslam.imu.allan import AllanResult


def plot_allan(res: AllanResult) -> Figure:
    import numpy as np
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 5))
    axes = fig.subplots(1, 2)
    for ax, adev, terms, unit, name in (
        (axes[0], res.accel_adev, res.accel_terms, res.accel_unit, "accelerometer"),
        (axes[1], res.gyro_adev, res.gyro_terms, res.gyro_unit, "gyroscope"),
    ):
        for j in range(3):
            ax.loglog(res.taus, adev[:, j], color=f"C{j}", label="xyz"[j])
            t = terms[j]
            ax.loglog(res.taus, t.white / np.sqrt(res.taus), color=f"C{j}", ls=":", lw=0.8)
            if t.random_walk is not None:
                ax.loglog(
                    res.taus, t.random_walk * np.sqrt(res.taus / 3), color=f"C{j}", ls="--", lw=0.8
                )
        ax.set_xlabel("tau [s]")
        ax.set_ylabel(f"Allan deviation [{unit}]")
        ax.set_title(f"{name}: dotted -1/2 (white), dashed +1/2 (random walk)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    return fig


def register(app: typer.Typer) -> None:
    @app.command("allan")
    @friendly_errors
    def allan_cmd(
        log_path: Path = typer.Argument(..., metavar="LOG", help="a long static IMU log"),
        gyro: Path | None = typer.Argument(
            None, help="gyroscope file, for imu_tk text in two files"
        ),
        fmt: ImuFormatChoice = typer.Option(ImuFormatChoice.auto, "--format", help=FORMAT_HELP),
        topic: str | None = typer.Option(None, help="IMU topic of a bag"),
        accel_unit: AccelUnitChoice | None = typer.Option(None, help="m/s^2, g or counts"),
        gyro_unit: GyroUnitChoice | None = typer.Option(None, help="rad/s, deg/s or counts"),
        columns: str | None = typer.Option(None, help="CSV column mapping"),
        out: Path = typer.Option(
            Path("allan_out"), "--out", help="results folder", callback=validate.out_folder()
        ),
    ) -> None:
        """Overlapped Allan deviation per axis: noise density, bias instability, random walk, Kalibr yaml."""
        import numpy as np

        from imuslam.imu.allan import allan
        from imuslam.io.plausible import check_gyro_noise, check_units
        from imuslam.io.results import write_results

        log = load_log(
            log_path, gyro, fmt.value, topic, value(accel_unit), value(gyro_unit), columns
        )
        check_units(log, hint="give --accel-unit / --gyro-unit")
        res = allan(log)
        white = float(np.median([t.white for t in res.gyro_terms]))
        check_gyro_noise(white, log.source, log.gyro_unit, hint="give --gyro-unit deg/s")
        data = _print_terms(res)
        kalibr_ok = _kalibr_or_why_not(res, topic)
        written = ["allan.png", "allan.csv", "config.yaml", "metrics.json (the noise terms)"]
        written += ["imu.yaml (Kalibr)"] if kalibr_ok is not None else []
        print_warnings(res.warnings)
        summary = {
            "source": res.source,
            "rate_hz": res.rate_hz,
            "terms": data,
            "warnings": res.warnings,
        }
        inputs = {"log": str(log_path), "gyro": None if gyro is None else str(gyro), "format": fmt.value,
                  "topic": topic, "accel_unit": res.accel_unit, "gyro_unit": res.gyro_unit, "columns": columns}  # fmt: skip
        write_results(
            out, config=inputs, metrics=summary, extra=lambda d: _write(res, kalibr_ok, d)
        )
        console.print(f"wrote {out}/{', '.join(written)}")


def _print_terms(res: Any) -> list[dict[str, Any]]:
    """The noise terms per axis, one table per sensor with the unit of each term in its header;
    returns them as records for metrics.json."""
    data = []
    for sensor, terms, u in (
        ("accel", res.accel_terms, res.accel_unit),
        ("gyro", res.gyro_terms, res.gyro_unit),
    ):
        rows = []
        for j, t in enumerate(terms):
            rw = (
                "-"
                if t.random_walk is None
                else f"{t.random_walk:.3g} ± {100 * (t.random_walk_rel_std or 0):.0f} %"
            )
            rows.append([f"{sensor} {'xyz'[j]}", f"{t.white:.3g} ± {100 * t.white_rel_std:.1f} %",
                         f"{t.bias_instability:.3g}", f"{t.bias_instability_tau_s:.3g}", rw])  # fmt: skip
            data.append({"sensor": sensor, "axis": "xyz"[j], **t.__dict__})
        console.print(
            table(
                f"Allan noise terms, {sensor}",
                ["term", f"white N [{u}/sqrt(Hz)]", f"bias instability B [{u}]", "at tau [s]",
                 f"random walk K [{u}*sqrt(Hz)]"],
                rows,
            )
        )  # fmt: skip
    return data


def _kalibr_or_why_not(res: Any, topic: str | None) -> dict[str, Any] | None:
    """Kalibr's imu.yaml fields, or None with the reason added to ``res.warnings`` (raw counts, no
    finite term); an upper-bound random walk is written with a warning."""
    import numpy as np

    kalibr = res.kalibr(topic or "/imu0")
    if "counts" in (res.accel_unit, res.gyro_unit):
        res.warnings.append(
            "imu.yaml not written: the log is in raw counts and Kalibr needs m/s^2 and rad/s "
            "(correct it with a calibration first, or give --accel-unit / --gyro-unit)"
        )
        return None
    if bad := [k for k, v in kalibr.items() if isinstance(v, float) and not np.isfinite(v)]:
        res.warnings.append(
            f"imu.yaml not written: no finite {', '.join(bad)} (no +1/2 slope in the Allan "
            "deviation: record a longer static log)"
        )
        return None
    for sensor, terms in (("accelerometer", res.accel_terms), ("gyroscope", res.gyro_terms)):
        if all(t.random_walk is None for t in terms):
            res.warnings.append(
                f"{sensor}_random_walk in imu.yaml is an upper bound from the longest tau "
                f"({res.taus[-1]:.0f} s): the log is too short to show the random walk"
            )
    return dict(kalibr)


def _write(res: AllanResult, kalibr: dict[str, Any] | None, out: Path) -> None:
    """allan.png, allan.csv and, when the log allows it, imu.yaml (Kalibr); the noise terms are
    metrics.json, written by the one writer."""
    import yaml

    from imuslam.io.atomic import write_atomic
    from imuslam.io.figures import save_figure

    save_figure(plot_allan(res), out / "allan.png")
    csv = "tau_s," + ",".join(f"accel_{a},gyro_{a}" for a in "xyz") + "\n"
    csv += "\n".join(
        f"{t:.6g},"
        + ",".join(f"{res.accel_adev[i, j]:.6g},{res.gyro_adev[i, j]:.6g}" for j in range(3))
        for i, t in enumerate(res.taus)
    )
    write_atomic(out / "allan.csv", csv + "\n")
    if kalibr is not None:
        write_atomic(out / "imu.yaml", yaml.safe_dump(kalibr, sort_keys=False))
