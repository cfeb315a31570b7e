"""The weights an evaluation plays: a run's checkpoint, or a shipped pretrained run.

A **pretrained run** is a directory that evaluates like a one-seed run directory without the
training state: ``config.json`` (the seed's settings), ``partners.json`` (the population and
its digest, as the run recorded them), ``params.safetensors`` (the policy's and the agent
model's parameters only, as ``policy/<path>`` and ``model/<path>`` tensors; its metadata holds
the format, the step and the checkpoint it came from) and ``card.json`` (where it came from and
what its evaluation gave). ``transam export`` writes one from a checkpoint; the package ships
some under ``transam/pretrained/NAME/`` (:func:`pretrained_names`), which ``transam evaluate
NAME`` plays without training. A few MB where a checkpoint is several times that: no
optimiser state, environment states or carries.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np
from flax.serialization import from_state_dict, to_state_dict
from flax.traverse_util import flatten_dict, unflatten_dict
from safetensors.numpy import load_file, save_file

from transam.rundir import (
    POPULATION_FILE,
    CheckpointError,
    checkpoints,
    find_checkpoint,
    load_run_config,
    newest_good_checkpoint,
    read_checkpoint,
    warn,
    write_atomic,
    write_json,
)
from transam.train.config import ConfigError, TrainConfig

WEIGHTS_FILE = "params.safetensors"
CARD_FILE = "card.json"
FORMAT = "transam-pretrained"
VERSION = "1"
PRETRAINED_DIR = Path(__file__).resolve().parents[1] / "pretrained"
"""Where the package's pretrained runs sit (one directory per name)."""


@dataclass(frozen=True)
class Weights:
    """What an evaluation needs of a trained run: its parameters, the step they were saved at
    and where they came from (a path relative to the run directory)."""

    policy_params: Any
    model_params: Any
    step: int
    source: str


def is_pretrained(run_dir: str | Path) -> bool:
    return (Path(run_dir) / WEIGHTS_FILE).is_file()


def is_shipped(run_dir: str | Path) -> bool:
    """Whether ``run_dir`` is one of the package's pretrained runs."""
    return is_pretrained(run_dir) and Path(run_dir).resolve().parent == PRETRAINED_DIR.resolve()


def pretrained_names() -> list[str]:
    """The shipped pretrained runs, by name."""
    if not PRETRAINED_DIR.is_dir():
        return []
    return sorted(p.name for p in PRETRAINED_DIR.iterdir() if is_pretrained(p))


def pretrained_dir(name: str) -> Path:
    """The directory of the shipped pretrained run ``name``."""
    if name not in pretrained_names():
        raise ConfigError(
            f"unknown pretrained run {name!r}; valid choices: {', '.join(pretrained_names())}"
        )
    return PRETRAINED_DIR / name


def resolve_run(run: str | Path) -> Path:
    """A run directory as given, or the shipped pretrained run of that name (a path that
    exists wins)."""
    path = Path(run)
    if path.exists():
        return path
    if str(run) in pretrained_names():
        return pretrained_dir(str(run))
    if len(path.parts) == 1:
        raise ConfigError(
            f"no run directory {str(run)!r} and no pretrained run of that name; shipped "
            f"pretrained runs: {', '.join(pretrained_names()) or 'none'}"
        )
    return path


def read_card(run_dir: str | Path) -> dict[str, Any]:
    path = Path(run_dir) / CARD_FILE
    return json.loads(path.read_text()) if path.exists() else {}


def _template(config: TrainConfig) -> Any:
    """The runner state's shapes (nothing is compiled or allocated)."""
    from transam.train.a2c import init_runner
    from transam.train.programs import env_and_model

    env, model = env_and_model(config)
    return jax.eval_shape(lambda k: init_runner(config, env, model, k), jax.random.key(0))


def restore_weights(
    config: TrainConfig, run_dir: Path, checkpoint: str | int | None, notes: list[str]
) -> Weights:
    """The weights of a pretrained run, of the named checkpoint, or of the newest checkpoint
    that verifies (each newer one that does not is reported and noted)."""
    from transam.train.a2c import steps_per_update

    template = _template(config)
    if is_pretrained(run_dir):
        if checkpoint is not None:
            raise ConfigError(f"{str(run_dir)!r} is a pretrained run: it has no --checkpoint")
        return _read_weights(run_dir / WEIGHTS_FILE, template)

    def weights(path: Path, state: Any) -> Weights:
        step = int(state.update) * steps_per_update(config)
        rel = path.relative_to(run_dir).as_posix()
        return Weights(state.policy_params, state.model_params, step, rel)

    path = find_checkpoint(run_dir, checkpoint)  # none at all: a clear error
    if checkpoint is not None:
        try:
            return weights(path, read_checkpoint(path, template))
        except CheckpointError as err:
            raise ConfigError(f"{err}; choose another with --checkpoint") from None

    def report(message: str) -> None:
        warn(message)
        notes.append(message)

    found = newest_good_checkpoint([run_dir], template, report=report)
    if found is None:
        names = ", ".join(p.name for _, p in sorted(checkpoints(run_dir).items()))
        raise ConfigError(f"no checkpoint of {str(run_dir)!r} verifies (have: {names})")
    chunk, (state,) = found
    return weights(checkpoints(run_dir)[chunk], state)


def _flat(prefix: str, tree: Any) -> dict[str, np.ndarray]:
    flat = flatten_dict(to_state_dict(tree), sep="/")
    return {f"{prefix}/{k}": np.asarray(v) for k, v in flat.items()}


def _unflat(prefix: str, tensors: dict[str, np.ndarray], template: Any, path: Path) -> Any:
    want = flatten_dict(to_state_dict(template), sep="/")
    got = {k[len(prefix) + 1 :]: v for k, v in tensors.items() if k.startswith(prefix + "/")}
    if set(got) != set(want):
        missing, extra = sorted(set(want) - set(got)), sorted(set(got) - set(want))
        raise ConfigError(
            f"{path}: the {prefix} parameters do not fit the run's settings "
            f"(missing: {', '.join(missing) or 'none'}; unexpected: {', '.join(extra) or 'none'})"
        )
    for k, v in want.items():
        if tuple(got[k].shape) != tuple(v.shape):
            raise ConfigError(
                f"{path}: {prefix}/{k} has shape {got[k].shape}, the settings give {v.shape}"
            )
    return from_state_dict(template, unflatten_dict({k: got[k] for k in want}, sep="/"))


def _read_weights(path: Path, template: Any) -> Weights:
    from safetensors import safe_open

    with safe_open(str(path), framework="numpy") as f:
        meta = f.metadata() or {}
    if meta.get("format") != FORMAT:
        raise ConfigError(f"{path} is not a {FORMAT} file (metadata: {meta})")
    tensors = load_file(str(path))
    policy = _unflat("policy", tensors, template.policy_params, path)
    model = _unflat("model", tensors, template.model_params, path)
    return Weights(policy, model, int(meta["step"]), WEIGHTS_FILE)


def export_run(
    run_dir: str | Path, out: str | Path, checkpoint: str | int | None = None, summary: str = ""
) -> dict[str, Any]:
    """Write the pretrained run ``out`` from one seed of a trained run (its newest verified
    checkpoint, or the named one); returns its card. Refuses an existing ``out`` that is not a
    pretrained run, and replaces one that is only after the new one is complete."""
    run_dir, out = Path(run_dir), Path(out)
    config = load_run_config(run_dir)
    if out.exists() and not is_pretrained(out):
        raise ConfigError(f"--out {str(out)!r} exists and is not a pretrained run")
    notes: list[str] = []
    w = restore_weights(config, run_dir, checkpoint, notes)
    top = run_dir if (run_dir / "config.json").exists() else run_dir.parent
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    identity = dataclasses.replace(config, out="", num_seeds=1).identity()
    write_json(tmp / "config.json", identity)
    if (top / POPULATION_FILE).exists():
        write_atomic(tmp / POPULATION_FILE, (top / POPULATION_FILE).read_bytes())
    tensors = {**_flat("policy", w.policy_params), **_flat("model", w.model_params)}
    meta = {"format": FORMAT, "version": VERSION, "step": str(w.step), "source": w.source}
    save_file(tensors, str(tmp / WEIGHTS_FILE), metadata=meta)
    card = {
        "env": config.env,
        "method": config.method,
        "partners": config.partners,
        "seed": config.seed,
        "step": w.step,
        "checkpoint": w.source,
        "summary": summary,
    }
    write_json(tmp / CARD_FILE, card)
    for p in tmp.iterdir():
        p.chmod(0o644)  # package data: readable by every user of an install
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
    return card
