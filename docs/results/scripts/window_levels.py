"""The window levels of a population: how well a team-agnostic MLP predicts each partner's
action from the controlled agent's last K observations (the current one and the K-1 changes
between successive ones; none before the episode's start), for each K given. K=1 and K=2 are
the recorded "own view" levels (``transam partners diversity``); K = the agent model's context
(5 for TransAM) is what its window holds. Random controlled agent, every 4th episode of each
team held out, the levels' own MLP (:func:`transam.partners.diversity.fit_hits`).

    python docs/results/scripts/window_levels.py --population runs/authors-pop --k 1 2 3 5 \
        --out runs/own-window/levels_1024.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from transam.compose import make_env
from transam.partners.diversity import (
    ClassifierConfig,
    PartnerSteps,
    collect_partner_steps,
    fit_hits,
)


def window_features(own: np.ndarray, k: int) -> np.ndarray:
    """[E, T, D] own observations -> [E, T, k*D]: o_t and o_{t-j+1} - o_{t-j} for j < k
    (a change reaching before the episode's first observation is zero)."""
    feats, prev = [own], own
    for _ in range(1, k):
        shifted = np.concatenate([prev[:, :1], prev[:, :-1]], 1)
        feats.append(prev - shifted)
        prev = shifted
    return np.concatenate(feats, -1)


def window_level(steps: PartnerSteps, k: int, num_actions: int, train_steps: int) -> dict:
    """Held-out accuracy of the MLP on the K-step window, overall and by step."""
    e, t, n, _ = steps.obs.shape
    f = window_features(steps.own_obs, k)
    slot = np.broadcast_to(np.eye(n, dtype=np.float32), (e, t, n, n))
    x = np.concatenate([np.broadcast_to(f[:, :, None], (e, t, n, f.shape[-1])), slot], -1)
    test = np.broadcast_to((steps.episode % 4 == 0)[:, None, None], (e, t, n))
    live = np.broadcast_to(steps.live[..., None], (e, t, n))
    times = np.broadcast_to(np.arange(t)[None, :, None], (e, t, n))
    x, y, test, times = x[live], steps.actions[live], test[live], times[live]
    cfg = ClassifierConfig(hidden=128, train_steps=train_steps, lr=1e-3, seed=0)
    right = fit_hits(x, y, num_actions, cfg, test)
    at = times[test]
    by_step = [round(float(right[at == i].mean()), 4) for i in range(t)]
    return {"accuracy": round(float(right.mean()), 4), "by_step": by_step}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", default="spread")
    ap.add_argument("--population", default="default", help="partners: a name or a directory")
    ap.add_argument("--k", type=int, nargs="+", default=[1, 2, 3, 5])
    ap.add_argument("--episodes", type=int, default=1024, help="episodes per team")
    ap.add_argument("--train-steps", type=int, default=20_000)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    env = make_env(args.env, partners=args.population)
    steps = collect_partner_steps(env, args.episodes, 0)
    out = {"env": args.env, "population": args.population, "episodes_per_team": args.episodes}
    for k in args.k:
        t0 = time.time()
        out[f"k{k}"] = window_level(steps, k, env.spec.other_num_actions, args.train_steps)
        print(f"K={k}: {out[f'k{k}']['accuracy']:.4f} ({time.time() - t0:.0f} s)", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
