"""The window levels of a population: how well a team-agnostic MLP predicts each partner's
action from the controlled agent's last K observations (the current one and the K-1 changes
between successive ones; none before the episode's start), for each K given. K=1 and K=2 are
the recorded "own view" levels (``transam partners diversity``); K = the agent model's context
(5 for TransAM) is what its window holds; K = the episode's length (25 on Spread), all of
its history, what a recurrent encoder (LIAM's) can hold. Random controlled agent (or, on
Spread, ``--agent landmark``: the landmark rule, whose states are nearer a trained policy's),
every 4th episode of each team held out, the levels' own MLP
(:func:`transam.partners.diversity.memoryless_accuracy`, view ``ownK``).

    python docs/results/scripts/window_levels.py --population runs/authors-pop --k 1 2 3 5 \
        --out runs/own-window/levels_1024.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from transam.compose import make_env
from transam.partners.diversity import (
    LevelsConfig,
    collect_partner_steps,
    memoryless_accuracy,
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", default="spread")
    ap.add_argument("--population", default="default", help="partners: a name or a directory")
    ap.add_argument("--k", type=int, nargs="+", default=[1, 2, 3, 5])
    ap.add_argument("--episodes", type=int, default=1024, help="episodes per team")
    ap.add_argument("--train-steps", type=int, default=20_000)
    ap.add_argument("--agent", choices=("random", "landmark"), default="random")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    env = make_env(args.env, partners=args.population)
    controlled = None
    if args.agent == "landmark":
        from transam.partners.spread import landmark_agent as controlled
    steps = collect_partner_steps(env, args.episodes, 0, controlled)
    out = {
        "env": args.env,
        "population": args.population,
        "agent": args.agent,
        "episodes_per_team": args.episodes,
    }
    cfg = LevelsConfig(train_steps=args.train_steps)
    for k in args.k:
        t0 = time.time()
        view = "own" if k == 1 else f"own{k}"
        level = memoryless_accuracy(steps, env.spec.other_num_actions, cfg, view=view)
        out[f"k{k}"] = {"accuracy": round(level["accuracy"], 4), "by_step": level["by_step"]}
        print(f"K={k}: {level['accuracy']:.4f} ({time.time() - t0:.0f} s)", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
