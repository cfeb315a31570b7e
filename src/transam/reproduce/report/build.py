"""``transam report OUT``: aggregate a grid directory into OUT/report/.

Writes ``results.json`` (every aggregated number and the claims,
:mod:`~transam.reproduce.report.results`), ``marl_eval.json`` (the raw data format of
InstaDeep's marl-eval), ``figures/*.png`` (the paper's figures) and ``report.md`` (commands,
budget, compute, tables, figures, the paper's claims with computed verdicts;
:mod:`~transam.reproduce.report.markdown`). Works on a partial grid: what is missing is listed,
never fatal.
"""

from __future__ import annotations

from pathlib import Path

from transam.reproduce.report import aggregate
from transam.reproduce.report.aggregate import ACC_NEWEST
from transam.reproduce.report.load import load_grid
from transam.reproduce.report.markdown import render
from transam.reproduce.report.results import FIGURES, build_results, grid_levels, marl_eval
from transam.rundir import write_atomic, write_json


def build_report(out: Path, draw: bool = True) -> Path:
    """Aggregate the grid in ``out`` into ``out/report/``; returns the path of report.md.
    ``draw=False`` skips the figures (the slow part; for tests of the numbers)."""
    from transam.reproduce.report import figures  # matplotlib: imported only when a report is built

    out = Path(out)
    grid = load_grid(out)
    levels = grid_levels(grid)
    table = aggregate.cells(grid, levels)
    report_dir = out / "report"
    fig_dir = report_dir / "figures"
    drawn: dict[str, str] = {}
    plans = {
        "returns": lambda p: figures.training_curves(
            table, "return", "evaluation return", "Return during training", p
        ),
        ACC_NEWEST: lambda p: figures.training_curves(
            table,
            ACC_NEWEST,
            "action accuracy (newest position)",
            "Action reconstruction accuracy during training",
            p,
        ),
        "episode": lambda p: figures.episode_evolution(table, "transam", p, levels),
        "probe": lambda p: figures.probe_curves(table, p),
        "pca": lambda p: figures.pca_scatter(grid.runs, "transam", p),
    }
    for key, plot in plans.items():
        path = fig_dir / FIGURES[key]
        if draw and plot(path) is not None:
            drawn[key] = f"figures/{FIGURES[key]}"
        else:
            path.unlink(missing_ok=True)  # not drawn: no stale figure from an earlier build
    results = build_results(grid, table, drawn, levels)
    report_dir.mkdir(parents=True, exist_ok=True)
    write_json(report_dir / "results.json", results)
    write_json(report_dir / "marl_eval.json", marl_eval(grid))
    path = report_dir / "report.md"
    write_atomic(path, render(results, table).encode())
    return path
