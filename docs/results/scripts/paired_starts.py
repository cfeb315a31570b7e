"""Our runs on the authors' own evaluation episodes: a paired comparison with their loop.

Their script evaluates on 100 episodes at each point, and all its seeds play the same ones
(docs/results/parity/README.md, "Their evaluation episodes"), so their curve carries a single
draw of episodes. A starts file (:mod:`transam.envs.starts`) holds those episodes, each
evaluation point a group labelled by its controlled step (made by replaying their script's
numpy calls; not part of the repository, as their code has no licence). Here each seed of each
run plays, at its checkpoint of the last chunk at or before a group's step, that group's
episodes (and every other group's); the returns on the same episodes are then compared with
their logged ones, and with the same checkpoints' returns on our own evaluation draws (how easy
their episodes are for our agent).

With ``--fixed NPZ`` (their per-episode returns of fixed controlled agents on the same
episodes: arrays ``noop`` [G, 100], optionally ``landmark``), the always-no-move agent is also
played in our environment from the same starts, per episode: with deterministic partners the
returns must agree to float precision if our environment and imported population are theirs.

    python docs/results/scripts/paired_starts.py --starts runs/authors-starts/eval_400k_600k.npz \
        --curve ../shared/reference/authors-loop/curve.csv runs/authors-seeds/seed_{4,5}.csv \
        --fixed runs/authors-starts/eval_400k_600k_fixed.npz \
        --out docs/results/parity/paired "TransAM, defaults=runs/parity/defaults"

Needs every checkpoint of the steps played (``transam train --keep-checkpoints 0``). Writes
``paired.md``, ``paired.json`` and ``paired.png`` into ``--out``; the evaluations go to
``--work`` (one JSON per seed and checkpoint, reused when re-run).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from parity_plot import T975, mean_ci


def interval(values: np.ndarray) -> tuple[float, float]:
    """Mean and 95% t half-width over seeds (the first axis)."""
    mean, half = mean_ci(values)
    return float(mean), float(half)


def welch(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Difference of means a − b and its 95% half-width (Welch; t with the smaller df)."""
    se = math.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    return float(a.mean() - b.mean()), T975.get(min(len(a), len(b)) - 1, 1.96) * se


def their_curve(path: Path, steps: list[int]) -> np.ndarray:
    with open(path) as f:
        rows = {int(r["controlled_steps"]): float(r["eval_return"]) for r in csv.DictReader(f)}
    missing = [s for s in steps if s not in rows]
    if missing:
        raise SystemExit(f"{path}: no evaluation at steps {missing}")
    return np.array([rows[s] for s in steps])


def seed_dirs(run: Path) -> list[Path]:
    dirs = sorted(run.glob("seed_*"), key=lambda p: int(p.name.split("_")[1]))
    return dirs or [run]


def chunk_at(seed_dir: Path, step: int) -> tuple[int, int, float]:
    """The last chunk at or before ``step``: (chunk, its step, its own evaluation return)."""
    lines = (seed_dir / "metrics.jsonl").read_text().splitlines()
    recs = [r for r in map(json.loads, lines) if r["step"] <= step]
    if not recs:
        raise SystemExit(f"{seed_dir}: no chunk at or before step {step}")
    r = recs[-1]
    return int(r["chunk"]), int(r["step"]), float(r["eval/return"])


def play(seed_dir: Path, starts: Path, chunk: int, work: Path) -> dict[str, Any]:
    from transam.evaluation.final import evaluate_starts
    from transam.rundir import starts_evaluation_path

    out = work / seed_dir.name / f"chunk_{chunk:06d}"
    path = starts_evaluation_path(out, starts)
    if path.exists():
        return dict(json.loads(path.read_text()))
    return evaluate_starts(seed_dir, starts, checkpoint=chunk, seed=0, out=out)


def fixed_check(starts: Path, run: Path, fixed: Path) -> dict[str, Any]:
    """The always-no-move controlled agent in our environment from the same starts, per
    episode, against their returns."""
    import jax
    import jax.numpy as jnp

    from transam.envs.rollout import make_random_rollout
    from transam.envs.starts import load_starts
    from transam.rundir import load_run_config
    from transam.train.programs import env_and_model

    env = env_and_model(load_run_config(seed_dirs(run)[0]))[0]
    st = load_starts(starts, env)
    theirs = np.load(fixed)["noop"].reshape(-1)
    rollout = make_random_rollout(
        env, st.episodes, env.spec.episode_len, lambda k, o: jnp.int32(0), st
    )
    ours = np.asarray(rollout(jax.random.key(0))[1].reward, np.float64).sum(0)
    diff = np.abs(ours - theirs)
    return {
        "episodes": len(ours),
        "ours_mean": float(ours.mean()),
        "theirs_mean": float(theirs.mean()),
        "max_abs_diff": float(diff.max()),
        "episodes_over_1e-3": int((diff > 1e-3).sum()),
    }


def figure(path: Path, steps: list[int], theirs: np.ndarray, runs: dict[str, Any]) -> None:
    """Per evaluation point: their logged return and each run's, on their episodes and on our
    own draws (means over seeds, each seed a dot)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.array(steps) / 1000
    fig, ax = plt.subplots(figsize=(8, 4))

    def draw(values: np.ndarray, label: str, style: str, shift: float) -> None:
        (line,) = ax.plot(x + shift, values.mean(0), style, label=label)
        for v in values:
            ax.plot(x + shift, v, ".", color=line.get_color(), alpha=0.4)

    draw(theirs, "the authors' loop (logged, their episodes)", "k-", 0.0)
    for label, r in runs.items():
        draw(np.array(r["on_their_episodes"]), f"{label}: their episodes", "-", 2.0)
        draw(np.array(r["on_our_draws"]), f"{label}: our own draws", "--", 4.0)
    ax.set_xlabel("controlled steps (thousands)")
    ax.set_ylabel("evaluation return (100 episodes)")
    ax.set_title("The same episodes: each evaluation point of the authors' loop")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("runs", nargs="+", help="LABEL=RUN_DIR")
    p.add_argument("--starts", type=Path, required=True)
    p.add_argument("--curve", type=Path, nargs="+", required=True, help="their CSV per seed")
    p.add_argument("--fixed", type=Path, help="their fixed-agent returns on the same episodes")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--work", type=Path, default=Path("runs/paired-starts"))
    args = p.parse_args()

    group = np.load(args.starts)["group"]
    steps = sorted(int(g) for g in np.unique(group))
    theirs = np.stack([their_curve(c, steps) for c in args.curve])  # [their seeds, G]
    result: dict[str, Any] = {
        "starts": str(args.starts),
        "steps": steps,
        "episodes_per_step": int((group == steps[0]).sum()),
        # Their per-seed means only: their curves are numbers of their unlicensed code, kept
        # out of the repository (docs/results/parity/README.md, "The authors' curve").
        "theirs": {
            "curves": [str(c) for c in args.curve],
            "per_seed_mean": theirs.mean(1).tolist(),
        },
        "runs": {},
    }
    lines = [
        f"| their {len(steps)} evaluation sets, steps {steps[0]:,}–{steps[-1]:,} | per seed "
        f"(mean over the {len(steps)} points) | mean ± 95% t |",
        "|---|---|---|",
    ]

    def row(label: str, per_seed: np.ndarray) -> None:
        m, h = interval(per_seed)
        seeds = ", ".join(f"{v:.2f}" for v in per_seed)
        lines.append(f"| {label} | {seeds} | {m:.2f} ± {h:.2f} |")

    their_means = theirs.mean(1)
    row("the authors' loop, logged (their episodes)", their_means)
    diffs = []
    for spec in args.runs:
        label, _, run_dir = spec.partition("=")
        run = Path(run_dir)
        matched, own, everywhere, ckpt_steps = [], [], [], []
        for d in seed_dirs(run):
            m_row, o_row, e_row, s_row = [], [], [], []
            for step in steps:
                chunk, at, own_return = chunk_at(d, step)
                res = play(d, args.starts, chunk, args.work / re.sub(r"\W+", "-", label))
                if res["step"] != at:
                    raise SystemExit(f"{d}: checkpoint {chunk} is step {res['step']}, not {at}")
                per_group = {str(k): v for k, v in res["per_group"].items()}  # JSON: str keys
                m_row.append(per_group[str(step)])
                o_row.append(own_return)
                e_row.append(res["return"]["mean"])
                s_row.append(at)
            matched.append(m_row)
            own.append(o_row)
            everywhere.append(e_row)
            ckpt_steps.append(s_row)
        mt, ow, ev = (np.array(x) for x in (matched, own, everywhere))
        row(f"{label}: on their episodes (checkpoint at each point)", mt.mean(1))
        row(f"{label}: on our own evaluation draws (same checkpoints)", ow.mean(1))
        row(f"{label}: on all {len(group)} of their episodes (each checkpoint)", ev.mean(1))
        d, h = welch(mt.mean(1), their_means)
        e, eh = interval(mt.mean(1) - ow.mean(1))
        corr = float(np.corrcoef(mt.mean(0), theirs.mean(0))[0, 1])
        diffs.append(
            f"- **{label}**: on the same episodes, ours − theirs = **{d:+.2f} ± {h:.2f}** "
            f"(Welch, 95%); their episodes against our own draws for the same checkpoints: "
            f"{e:+.2f} ± {eh:.2f}; per evaluation point, the correlation of our mean with "
            f"theirs is {corr:.2f}."
        )
        result["runs"][label] = {
            "run": run_dir,
            "checkpoint_steps": ckpt_steps,
            "on_their_episodes": mt.tolist(),
            "on_our_draws": ow.tolist(),
            "on_all_their_episodes": ev.tolist(),
            "ours_minus_theirs": [d, h],
            "their_episodes_minus_our_draws": [e, eh],
            "per_point_correlation": corr,
        }
    lines += ["", *diffs]
    if args.fixed:
        fc = fixed_check(args.starts, Path(args.runs[0].partition("=")[2]), args.fixed)
        result["fixed_noop"] = fc
        lines += [
            "",
            f"The always-no-move controlled agent on the same {fc['episodes']} episodes: ours "
            f"{fc['ours_mean']:.3f}, theirs {fc['theirs_mean']:.3f}; largest per-episode "
            f"difference {fc['max_abs_diff']:.2g} ({fc['episodes_over_1e-3']} of them over "
            "1e-3).",
        ]
    args.out.mkdir(parents=True, exist_ok=True)
    figure(args.out / "paired.png", steps, theirs, result["runs"])
    (args.out / "paired.json").write_text(json.dumps(result, indent=1) + "\n")
    (args.out / "paired.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
