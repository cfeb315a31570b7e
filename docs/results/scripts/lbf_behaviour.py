"""How an LBF controlled agent gets its return: loads, foods and who collects them (issue 36).

Plays trained runs (their newest checkpoint) and lbforaging's H3 ("nearest food it can load
alone") as the controlled agent on the same episodes (the same starts and partner teams,
balanced over the population as ``transam evaluate`` does; the partners' own sampling then
differs), records every step's game state and both agents' actions, and prints one column per
agent:

    python docs/results/scripts/lbf_behaviour.py runs/lbf-6m/seed_0 runs/lbf-6m/seed_1 \
        --episodes 500 [--greedy] [--partners train|heldout]

Runs of lbf_relative.py (``lbf-rel``: the controlled agent's observation relative to itself)
are played in that variant, on the same episodes (the same game states and partners).

What the rows mean (each episode is one parallel copy's first episode, at most 50 steps; a
"load" is the agent choosing action 5; it is *valid* when a food is 4-adjacent, else the game
turns it into "none"):

* return: the controlled agent's episode return; partner: the partner's return on the same
  episodes; ± is the standard error over episodes.
* load share of steps; valid share of loads.
* of valid loads: at a food the agent can load alone (food level <= its own level), at one that
  needs the partner; of each, the share that collected the food this step; of the loads at a
  food that needs the partner, the share with the partner adjacent to it, and loading it.
* failed loads per episode (a valid load that did not collect: waiting at a food).
* foods collected per episode: by the agent alone, by the partner alone, jointly; and the
  controlled agent's return from its solo and from its joint collections.
* foods the agent could load alone at the episode's start, and the return split by the agent's
  own level.

Rewards of both agents are recomputed with ``transam.envs.lbf.step_state`` from each recorded
state and joint action, and the controlled agent's are checked against the environment's.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from transam.compose import make_env
from transam.envs import lbf
from transam.envs.core import ControlledEnv
from transam.evaluation.final import balanced_partners, population_for
from transam.evaluation.weights import resolve_run, restore_weights
from transam.models import make_model
from transam.partners import lbf as lbf_partners
from transam.rundir import load_run_config
from transam.train.a2c import act, batch_carry, env_step, first_step, make_policy

# An agent: (init(n) -> carry, step(carry, x, env_state, key) -> (carry, actions [n])).
Agent = tuple[Callable[[int], Any], Callable[[Any, Any, Any, jax.Array], tuple[Any, jax.Array]]]


def rule_agent(policy: Callable[[jax.Array, jax.Array], jax.Array]) -> Agent:
    """A memoryless rule of the controlled agent's observation."""

    def step(carry: Any, x: Any, env_state: Any, key: jax.Array) -> tuple[Any, jax.Array]:
        del env_state
        n = x.obs.shape[0]
        return carry, jax.vmap(policy)(jax.random.split(key, n), x.obs)

    return (lambda n: (), step)


def run_agent(run_dir: str, greedy: bool, env: ControlledEnv) -> tuple[Agent, str]:
    """A trained run's newest checkpoint, acting as in its evaluation (sampled, or argmax)."""
    path = resolve_run(run_dir)
    config = load_run_config(path)
    config = dataclasses.replace(config, eval=dataclasses.replace(config.eval, greedy=greedy))
    notes: list[str] = []
    w = restore_weights(config, path, None, notes)
    model = make_model(config.method, env.spec, config.model, config.baseline)
    policy = make_policy(config, env)
    dropout = config.acting_dropout

    def init(n: int) -> Any:
        return (policy.init_carry((n,)), batch_carry(model.init_carry(env.spec), n))

    def step(carry: Any, x: Any, env_state: Any, key: jax.Array) -> tuple[Any, jax.Array]:
        pc, mc = carry
        k_act, k_drop = jax.random.split(key)
        pc, mc, _, logits, _ = act(
            policy,
            model,
            w.policy_params,
            w.model_params,
            pc,
            mc,
            x,
            env_state,
            k_drop if dropout else None,
        )
        if greedy:
            action = jnp.argmax(logits, -1).astype(jnp.int32)
        else:
            action = jax.random.categorical(k_act, logits).astype(jnp.int32)
        return (pc, mc), action

    label = f"{config.method} {path.parent.name}/{path.name} @{w.step // 1000}k"
    return (init, step), label


def play(env: ControlledEnv, agent: Agent, n: int, seed: int) -> dict[str, np.ndarray]:
    """Per-step records [T, n] of n episodes (episode i plays partner i mod M)."""
    init, agent_step = agent
    partner = jnp.asarray(balanced_partners(n, env.num_partners))
    k_reset, k_run = jax.random.split(jax.random.key(seed))

    def run(key: jax.Array) -> Any:
        state0, obs = jax.vmap(env.reset)(jax.random.split(k_reset, n), partner)

        def body(carry: Any, key: jax.Array) -> Any:
            env_state, x, ac, alive = carry
            k_act, k_env = jax.random.split(key)
            ac, action = agent_step(ac, x, env_state, k_act)
            game = env_state.game
            new_state, ts, x = env_step(env, k_env, env_state, action)
            out = {
                "agent_pos": game.agent_pos,
                "agent_level": game.agent_level,
                "food_pos": game.food_pos,
                "food_level": game.food_level,
                "total_food": game.total_food,
                "actions": jnp.stack([action, ts.record.other_actions[:, 0]], -1),
                "reward": ts.reward,
                "live": alive,
            }
            return (new_state, x, ac, alive & ~ts.done), out

        init_carry = (state0, first_step(obs), init(n), jnp.ones((n,), bool))
        _, out = jax.lax.scan(body, init_carry, jax.random.split(k_run, env.spec.episode_len))
        return out

    return {k: np.asarray(v) for k, v in jax.device_get(jax.jit(run)(k_run)).items()}


def analyse(rec: dict[str, np.ndarray], config: lbf.Config) -> dict[str, Any]:
    """Per-episode and per-load statistics of one agent's records (see the module docstring)."""
    T, n = rec["reward"].shape
    flat = {k: v.reshape(T * n, *v.shape[2:]) for k, v in rec.items()}
    state = lbf.State(
        agent_pos=jnp.asarray(flat["agent_pos"]),
        agent_level=jnp.asarray(flat["agent_level"]),
        food_pos=jnp.asarray(flat["food_pos"]),
        food_level=jnp.asarray(flat["food_level"]),
        total_food=jnp.asarray(flat["total_food"]),
    )
    step = jax.jit(jax.vmap(lambda s, a: lbf.step_state(s, a, config)))
    nxt, rewards, _ = step(state, jnp.asarray(flat["actions"]))
    valid = np.asarray(jax.vmap(lambda s: lbf.valid_actions(s, config.grid_size))(state))
    rewards = np.asarray(rewards).reshape(T, n, 2)
    live = rec["live"].astype(bool)
    if not np.allclose(rewards[..., 0] * live, rec["reward"] * live, atol=1e-6):
        raise AssertionError("recomputed rewards differ from the environment's")

    acts = rec["actions"]  # [T, n, 2]
    pos = rec["agent_pos"]  # [T, n, 2, 2]
    lvl = rec["agent_level"]  # [T, n, 2]
    fpos, flvl = rec["food_pos"], rec["food_level"]  # [T, n, F, 2], [T, n, F]
    after = np.asarray(nxt.food_level).reshape(T, n, -1)
    alive = flvl > 0
    dist = np.abs(pos[:, :, :, None, :] - fpos[:, :, None, :, :]).sum(-1)  # [T, n, 2, F]
    adj = (dist == 1) & alive[:, :, None, :]
    is_valid = np.take_along_axis(valid.reshape(T, n, 2, 6), acts[..., None], -1)[..., 0]
    load = (acts == lbf.LOAD) & live[..., None]
    vload = load & is_valid  # [T, n, 2]
    # The food each agent is next to (unique in spawned episodes: foods are spaced apart).
    food_of = np.argmax(adj, -1)  # [T, n, 2]
    my_food = food_of[..., 0]
    my_fl = np.take_along_axis(flvl, my_food[..., None], -1)[..., 0]
    alone_ok = my_fl <= lvl[..., 0]
    partner_adj = np.take_along_axis(adj[:, :, 1, :], my_food[..., None], -1)[..., 0]
    partner_loads_same = vload[..., 1] & partner_adj & (food_of[..., 1] == my_food)
    collected_food = alive & (after == 0) & live[..., None]  # [T, n, F]
    my_collect = vload[..., 0] & np.take_along_axis(collected_food, my_food[..., None], -1)[..., 0]

    # Who collected each food: the valid loaders adjacent to it.
    pool = vload[:, :, :, None] & adj  # [T, n, 2, F]
    by_me = collected_food & pool[:, :, 0] & ~pool[:, :, 1]
    by_partner = collected_food & pool[:, :, 1] & ~pool[:, :, 0]
    joint = collected_food & pool[:, :, 0] & pool[:, :, 1]
    mine_r = rewards[..., 0] * live
    my_joint_r = np.where(joint.any(-1), mine_r, 0.0)

    # Navigation: the nearest food the agent can load alone, before and after the step.
    alone_food = alive & (flvl <= lvl[..., :1])  # [T, n, F]
    new_pos = np.asarray(nxt.agent_pos).reshape(T, n, 2, 2)[:, :, 0]
    d_now = np.where(alone_food, dist[:, :, 0], 999).min(-1)
    d_next = np.where(alone_food, np.abs(new_pos[:, :, None] - fpos).sum(-1), 999).min(-1)
    en_route = live & alone_food.any(-1) & (d_now > 1)
    at_alone = live & (d_now == 1)
    stayed = live & (new_pos == pos[:, :, 0]).all(-1) & ~my_collect

    ep = {  # per-episode values
        "return": mine_r.sum(0),
        "partner return": (rewards[..., 1] * live).sum(0),
        "return from solo loads": (mine_r - my_joint_r).sum(0),
        "return from joint loads": my_joint_r.sum(0),
        "foods by agent alone": by_me.sum((0, 2)),
        "foods by partner alone": by_partner.sum((0, 2)),
        "foods jointly": joint.sum((0, 2)),
        "failed loads (valid, no food)": (vload[..., 0] & ~my_collect).sum(0),
        "invalid loads": (load[..., 0] & ~is_valid[..., 0]).sum(0),
        "steps": live.sum(0),
    }
    # foods left when the episode ended: the last live step's food levels after it.
    last = np.maximum(live.sum(0) - 1, 0)
    ep["foods left"] = (after[last, np.arange(n)] > 0).sum(-1)
    ep["foods it can load alone at start"] = ((flvl[0] > 0) & (flvl[0] <= lvl[0, :, :1])).sum(-1)
    v0 = vload[..., 0]
    failed = v0 & ~my_collect
    c = {
        "steps": live.sum(),
        "loads": load[..., 0].sum(),
        "valid": v0.sum(),
        "alone": (v0 & alone_ok).sum(),
        "alone collected": (v0 & alone_ok & my_collect).sum(),
        "needs": (v0 & ~alone_ok).sum(),
        "needs collected": (v0 & ~alone_ok & my_collect).sum(),
        "needs partner adjacent": (v0 & ~alone_ok & partner_adj).sum(),
        "needs partner loading": (v0 & ~alone_ok & partner_loads_same).sum(),
        "failed": failed.sum(),
        "en route": en_route.sum(),
        "closer": (en_route & (d_next < d_now)).sum(),
        "farther": (en_route & (d_next > d_now)).sum(),
        "at alone": at_alone.sum(),
        "at alone loads": (at_alone & vload[..., 0] & alone_ok).sum(),
        "stayed": stayed.sum(),
        "failed needs": (failed & ~alone_ok).sum(),
    }
    shares = [  # (label, numerator, denominator)
        ("load share of steps", "loads", "steps"),
        ("valid share of loads", "valid", "loads"),
        ("valid loads at an alone-loadable food", "alone", "valid"),
        ("  of these, collected", "alone collected", "alone"),
        ("valid loads at a food needing the partner", "needs", "valid"),
        ("  of these, collected", "needs collected", "needs"),
        ("  of these, partner adjacent to it", "needs partner adjacent", "needs"),
        ("  of these, partner loading it too", "needs partner loading", "needs"),
        ("failed valid loads at a food needing partner", "failed needs", "failed"),
        ("steps en route (alone-loadable food, not adj.)", "en route", "steps"),
        ("  of these, closer to the nearest one", "closer", "en route"),
        ("  of these, farther from it", "farther", "en route"),
        ("steps adjacent to an alone-loadable food", "at alone", "steps"),
        ("  of these, loading it", "at alone loads", "at alone"),
        ("steps staying in place without collecting", "stayed", "steps"),
    ]
    return {"episodes": ep, "counts": c, "shares": shares, "level": lvl[0, :, 0]}


def fmt_mean(x: np.ndarray, digits: int = 3) -> str:
    x = np.asarray(x, np.float64)
    return f"{x.mean():.{digits}f} ± {x.std() / np.sqrt(len(x)):.{digits}f}"


def table(results: dict[str, dict[str, Any]]) -> str:
    names = list(results)
    width = max(26, *(len(n) + 2 for n in names))
    rows = [f"{'':46s}" + "".join(f"{n:>{width}s}" for n in names)]

    def line(label: str, cells: list[str]) -> None:
        rows.append(f"{label:46s}" + "".join(f"{c:>{width}s}" for c in cells))

    first = results[names[0]]
    for key in first["episodes"]:
        digits = 3 if "return" in key else 2
        line(f"{key}/ep.", [fmt_mean(results[n]["episodes"][key], digits) for n in names])
    for label, num, den in first["shares"]:
        cells = []
        for r in results.values():
            c = r["counts"]
            cells.append(f"{c[num] / max(c[den], 1):.3f} ({c[num]}/{c[den]})")
        line(label, cells)
    for level in (1, 2):
        cells = []
        for r in results.values():
            sel = r["level"] == level
            cells.append(f"{fmt_mean(r['episodes']['return'][sel])} (n={sel.sum()})")
        line(f"return, own level {level}", cells)
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="*", help="run directories (one seed each)")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--partners", default="train", help="train (the run's) or heldout")
    parser.add_argument("--greedy", action="store_true", help="argmax actions (default: sample)")
    args = parser.parse_args(argv)

    import lbf_relative  # beside this script: registers lbf-rel, which its runs need

    lbf_relative.register()
    trained = load_run_config(resolve_run(args.runs[0])).partners if args.runs else "default"
    choice = population_for(trained, args.partners)
    env = make_env("lbf", partners=choice)
    config = env.game.config
    agents: dict[str, tuple[Agent, ControlledEnv]] = {
        "H3": (rule_agent(lbf_partners.heuristic(False, "own", config)), env),
        "H1": (rule_agent(lbf_partners.heuristic(False, None, config)), env),
    }
    for run in args.runs:
        run_env = env
        if load_run_config(resolve_run(run)).env == lbf_relative.NAME:
            run_env = make_env(lbf_relative.NAME, partners=choice)
        agent, label = run_agent(run, args.greedy, run_env)
        agents[label] = (agent, run_env)
    results = {}
    for name, (agent, agent_env) in agents.items():
        results[name] = analyse(play(agent_env, agent, args.episodes, args.seed), config)
    mode = "greedy" if args.greedy else "sampled"
    print(
        f"LBF behaviour: {args.episodes} episodes, seed {args.seed}, partners {args.partners} "
        f"({env.population.name}), runs' actions {mode}; ± standard error over episodes; "
        "shares: count in brackets"
    )
    print(table(results))


if __name__ == "__main__":
    main()
