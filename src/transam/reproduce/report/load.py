"""Reading a grid directory (see :mod:`transam.reproduce.grid`) without trusting it to be complete.

Every file is optional: a run may be missing, unfinished (no final.json), or finished but not
yet evaluated (no eval_*.json); a file being written by another process may be torn. Each run
is read into a :class:`RunData` with a status and the problems met, and nothing here raises
for a partial grid.

Metric names of older runs are read as today's (:data:`~transam.models.base.LEGACY_METRICS`:
``action_accuracy``, in metrics.jsonl, final.json and eval_*.json, is the newest-position
accuracy ``action_accuracy_newest``), so old run directories load unchanged.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from transam import registry
from transam.models.base import LEGACY_METRICS
from transam.rundir import EVAL_PARTNERS, evaluation_path, projection_path, read_metrics
from transam.train.config import ConfigError

# The paper's order.
ENV_ORDER: tuple[str, ...] = registry.PAPER_ENVS
METHOD_ORDER: tuple[str, ...] = registry.PAPER_METHODS
Status = Literal["missing", "unfinished", "finished"]


@dataclass(frozen=True)
class Projection:
    """An evaluation's 2-D PCA of the embeddings (eval_{partners}_pca.npz of
    :mod:`transam.evaluation.final`)."""

    coords: np.ndarray
    """(N, 2)"""
    partner: np.ndarray
    """(N,) partner index of each episode"""
    team_names: list[str] | None
    explained_variance: list[float] | None


@dataclass
class RunData:
    """What one run directory holds."""

    env: str
    method: str
    seed: int
    rel: str
    status: Status = "missing"
    metrics: list[dict[str, Any]] = field(default_factory=list)
    final: dict[str, Any] | None = None
    """the last metrics record, from final.json"""
    evals: dict[str, dict[str, Any]] = field(default_factory=dict)
    """partners ("train" / "heldout") -> eval_{partners}.json"""
    pca: dict[str, Projection] = field(default_factory=dict)
    """partners -> eval_{partners}_pca.npz"""
    problems: list[str] = field(default_factory=list)


@dataclass
class Grid:
    out: Path
    info: dict[str, Any]
    """grid.json ({} when absent)"""
    runs: list[RunData]
    expected: list[str]
    """run dirs grid.json names (in its order)"""
    launch_seconds: float
    """sum of the per-run "done" seconds in log/*.jsonl"""


def order_key(order: tuple[str, ...]) -> Any:
    """Sort known names in the paper's order, unknown ones after them, alphabetically."""
    return lambda name: (order.index(name) if name in order else len(order), name)


def parse_rel(rel: str) -> tuple[str, str, int] | None:
    """``runs/ENV/METHOD/seed_S`` -> (env, method, seed), or None for anything else."""
    from transam.reproduce.grid import spec_from_rel

    try:
        spec = spec_from_rel(rel)
    except ValueError:
        return None
    return spec.env, spec.method, spec.seed


def _read_json(path: Path, problems: list[str]) -> Any:
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        problems.append(f"{path.name}: unreadable ({type(err).__name__})")
        return None


def read_pca(path: Path) -> Projection | None:
    """The projection in ``path`` (keys ``coords``, ``partner``, optional ``team_names`` and
    ``explained_variance``), or None when unreadable or shaped otherwise."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: np.asarray(data[k]) for k in data.files}
    except (OSError, ValueError, KeyError):
        return None
    coords, partner = arrays.get("coords"), arrays.get("partner")
    if coords is None or coords.ndim != 2 or coords.shape[1] < 2:
        return None
    n = coords.shape[0]
    if partner is None or partner.shape != (n,):
        partner = np.zeros(n, dtype=int)
    teams = arrays.get("team_names")
    ev = arrays.get("explained_variance")
    return Projection(
        coords[:, :2].astype(float),
        partner,
        [str(t) for t in teams.tolist()] if teams is not None and teams.ndim == 1 else None,
        [float(v) for v in ev.tolist()] if ev is not None and ev.ndim == 1 else None,
    )


def renamed(record: dict[str, Any]) -> dict[str, Any]:
    """``record`` with legacy metric names replaced, bare or after a ``train/``/``eval/``
    prefix (a name already present in today's form wins)."""
    out: dict[str, Any] = {}
    for key, value in record.items():
        prefix, sep, name = key.rpartition("/")
        if name not in LEGACY_METRICS:
            out[key] = value
        elif (new := prefix + sep + LEGACY_METRICS[name]) not in record:
            out[new] = value
    return out


def renamed_eval(ev: dict[str, Any]) -> dict[str, Any]:
    """An eval_*.json with legacy metric names replaced (top level and per_step curves)."""
    ev = renamed(ev)
    if isinstance(ev.get("per_step"), dict):
        ev["per_step"] = renamed(ev["per_step"])
    return ev


def read_run(out: Path, rel: str) -> RunData | None:
    parsed = parse_rel(rel)
    if parsed is None:
        return None
    env, method, seed = parsed
    run = RunData(env, method, seed, rel)
    d = out / rel
    if not (d / "config.json").exists():
        return run
    run.status = "unfinished"
    run.metrics = [renamed(r) for r in read_metrics(d / "metrics.jsonl")]
    final = _read_json(d / "final.json", run.problems)
    if isinstance(final, dict) and final.get("seeds"):
        run.status = "finished"
        first = final["seeds"][0]
        run.final = renamed(first) if isinstance(first, dict) and first else None
        run.final = run.final or (run.metrics[-1] if run.metrics else None)
    for partners in EVAL_PARTNERS:
        path = evaluation_path(d, partners)
        ev = _read_json(path, run.problems)
        if isinstance(ev, dict) and isinstance(ev.get("return"), dict):
            run.evals[partners] = renamed_eval(ev)
        elif ev is not None:
            run.problems.append(f"{path.name}: no 'return' entry")
        npz = projection_path(d, partners)
        if npz.exists():
            pca = read_pca(npz)
            if pca is None:
                run.problems.append(f"{npz.name}: unreadable or without (N, 2) coords")
            else:
                run.pca[partners] = pca
    return run


def load_grid(out: Path) -> Grid:
    """Every run grid.json names plus any run directory found under runs/ (sorted in the
    paper's order). Raises only when ``out`` holds neither grid.json nor runs/."""
    info = _read_json(out / "grid.json", []) if (out / "grid.json").exists() else None
    if not isinstance(info, dict) and not (out / "runs").is_dir():
        raise ConfigError(
            f"{str(out)!r} holds no grid (neither grid.json nor runs/): pass the --out of "
            "`transam reproduce`"
        )
    info = info if isinstance(info, dict) else {}
    expected = [r for r in info.get("runs", []) if isinstance(r, str)]
    found = [str(p.relative_to(out)) for p in sorted(out.glob("runs/*/*/seed_*")) if p.is_dir()]
    rels = list(dict.fromkeys(expected + found))
    runs = [r for r in (read_run(out, rel) for rel in rels) if r is not None]
    envs, methods = order_key(ENV_ORDER), order_key(METHOD_ORDER)
    runs.sort(key=lambda r: (envs(r.env), methods(r.method), r.seed))
    seconds = 0.0
    for log in sorted((out / "log").glob("*.jsonl")):
        for event in read_metrics(log):
            if event.get("event") == "done" and isinstance(event.get("seconds"), int | float):
                seconds += float(event["seconds"])
    return Grid(out, info, runs, expected, seconds)
