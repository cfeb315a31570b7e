"""Issue 36 reading (b): NAM on LBF with the controlled agent's observation relative to itself.

The same run as docs/results/lbf's 3M NAM runs (the archived learnability/nam/config.json:
every setting, 2 vmapped seeds) with one change, the game's ``relative_obs=True``
(``transam.envs.lbf.Config``): foods and the partner as offsets from the controlled agent.
The partners (the default learned population) see what they always see. The CLI has no game
options, so this registers the variant as the environment ``lbf-rel`` (the registry's
documented extension point) and trains/evaluates in-process:

    python docs/results/scripts/lbf_relative.py train runs/lbf-rel [--total-steps 3000000]
    python docs/results/scripts/lbf_relative.py evaluate runs/lbf-rel/seed_0 --episodes 500
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from transam import registry
from transam.compose import partner_population
from transam.envs import lbf

NAME = "lbf-rel"
BASE = Path(__file__).resolve().parents[1] / "lbf" / "learnability" / "nam" / "config.json"


@dataclasses.dataclass(frozen=True)
class RelConfig(lbf.Config):
    relative_obs: bool = True


def _population(choice: str) -> Any:
    def load(config: RelConfig) -> Any:
        return partner_population("lbf", lbf.Config(**dataclasses.asdict(config)), choice)

    return load


def register() -> None:
    registry.register_env(
        name=NAME,
        title="LBF, relative observation",
        game=SimpleNamespace(Config=RelConfig, make_env=lbf.make_env),
        episode_len=50,
        populations={"default": _population("default"), "heldout": _population("heldout")},
        replace=True,
    )


def base_config(out: str, total_steps: int | None, env: str = NAME) -> Any:
    """The archived 3M NAM run's config with ``env`` (default: this variant), ``out`` and the
    run length (evaluations scaled to keep their number)."""
    from transam.rundir import read_config

    config = read_config(BASE)
    steps = total_steps or config.total_steps
    every = config.eval.every_episodes * steps // config.total_steps
    return dataclasses.replace(
        config,
        env=env,
        out=out,
        total_steps=steps,
        progress=False,
        eval=dataclasses.replace(config.eval, every_episodes=every),
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train")
    t.add_argument("out")
    t.add_argument("--total-steps", type=int, default=None)
    t.add_argument("--resume", action="store_true")
    e = sub.add_parser("evaluate")
    e.add_argument("run")
    e.add_argument("--episodes", type=int, default=500)
    e.add_argument("--partners", default="train")
    args = parser.parse_args(argv)
    register()
    if args.cmd == "train":
        from transam.train.loop import train

        config = dataclasses.replace(base_config(args.out, args.total_steps), resume=args.resume)
        print(json.dumps({"env": config.env, "total_steps": config.total_steps}), flush=True)
        result = train(config)
        print(result.final)
    else:
        from transam.evaluation.final import evaluate_run

        found = evaluate_run(args.run, episodes=args.episodes, partners=args.partners)
        r = found["return"]
        print(
            f"{args.run} ({args.partners}): return {r['mean']:.4f} ± "
            f"{r['std'] / args.episodes**0.5:.4f} (s.e.), entropy {found['policy_entropy']:.3f}, "
            f"actions {[round(a, 3) for a in found['action_frequency']]}"
        )


if __name__ == "__main__":
    main()
