"""``imuslam study``: a study of simulated cells (simulate -> calibrate -> align -> estimate -> evaluate)
run on Dask, with a report that answers each claim."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    from imuslam.cli.common import (
        console,
        friendly_errors,
        progress_option,
        show_progress,
        table,
    )

    @app.command("study")
    @friendly_errors
    def study_cmd(
        study_file: Path | None = typer.Argument(None, help="study YAML (see examples/seeds.yaml)"),
        out: Path = typer.Option(
            Path("study_out"), "--out", help="results folder (its cells/ cache resumes a study)"
        ),
        scheduler: str | None = typer.Option(
            None, "--scheduler", help="address of a running Dask scheduler, e.g. tcp://host:8786"
        ),
        workers: int | None = typer.Option(
            None,
            "--workers",
            min=1,
            max=256,
            help="local worker processes (default: one per core)",
        ),
        serial: bool = typer.Option(
            False, "--serial", help="run the cells one after another in this process"
        ),
        quick: bool = typer.Option(False, "--quick", help="the built-in quick study (a few cells)"),
        progress: bool = progress_option(),
    ) -> None:
        """Run a study: cells on Dask, results.parquet/.csv, report.html per claim; or a study of
        recorded logs (a YAML with 'logs'): the estimator once per calibration, maps and
        trajectories compared."""
        import logging

        logging.getLogger("numexpr").setLevel(logging.WARNING)
        from imuslam.errors import EstimatorError, InputError
        from imuslam.study.config import parse_study, read_study_data
        from imuslam.study.logconfig import is_log_study
        from imuslam.study.presets import QUICK
        from imuslam.study.report import PAIR_COLUMNS, READING, analyse, pair_table_rows
        from imuslam.study.runner import run_study

        if quick == (study_file is not None):
            raise InputError("give a study YAML or --quick (one of them)")
        if scheduler and (serial or workers):
            raise InputError(
                "--scheduler runs on that cluster's workers; drop --serial / --workers"
            )
        src = "--quick" if quick else str(study_file)
        data = QUICK if quick else read_study_data(study_file)  # type: ignore[arg-type]
        if is_log_study(data):
            return _log_study(data, study_file, out, scheduler, workers, show_progress(progress))  # type: ignore[arg-type]
        study = parse_study(data, src)
        res = run_study(study, out, scheduler, workers, serial, show_progress(progress), source=src)
        n_err = int((res.table["status"] != "ok").sum())
        console.print(
            f"{len(res.table)} cells on {res.backend}: {res.n_run} run, {res.n_cached} from the cache, {n_err} failed"
        )
        rows, pair_rows = [], []
        for c in study.claims:
            a = analyse(c, res.table, study.seeds)
            rows.append([c.name, c.seed_doc or "-", c.compare, c.metric, a.verdict])
            pair_rows += pair_table_rows(a)
        console.print(table("Claims", ["claim", "seed", "compared", "metric", "verdict"], rows))
        if pair_rows:
            console.print(
                table("Pairs (difference > 0: as claimed)", list(PAIR_COLUMNS), pair_rows)
            )
        for note in READING:  # what a cell, the difference's sign and each verdict mean
            console.print(note, markup=False, highlight=False)
        console.print(
            f"wrote {out}/report.html, report.md, results.parquet, results.csv, study.yaml"
        )
        if n_err and n_err == len(res.table):  # nothing was measured: the study failed
            first = str(res.table["error"].iloc[0])
            raise EstimatorError(
                f"every one of the {n_err} cells failed (see {out}/results.csv); the first: {first}"
            )


def _log_study(
    data: object, study_file: Path, out: Path, scheduler: str | None, workers: int | None,
    progress: bool,
) -> None:  # fmt: skip
    """A study of recorded logs (``study.logstudy``): run, print each log's table, write the report."""
    from imuslam.cli.common import console, table
    from imuslam.errors import InputError

    if scheduler or workers:
        raise InputError(
            f"{'--scheduler' if scheduler else '--workers'}: a study of recorded logs runs its runs "
            "one after another in this process; drop the option"
        )
    from imuslam.study.logconfig import parse_log_study
    from imuslam.study.logreport import table_rows
    from imuslam.study.logstudy import run_log_study

    study = parse_log_study(data, str(study_file), study_file.parent)
    res = run_log_study(study, out, str(study_file), progress)
    for spec in study.logs:
        head, rows = table_rows(spec, [r for r in res.runs if r.log == spec.name], imu=False)
        console.print(table(f"{spec.name}: {spec.estimator} on {Path(spec.path).name}", head, rows))
    console.print(f"wrote {out}/report.html, report.md, results.csv, study.yaml, <log>/<run>.tum")
