"""Issue 36, LBF: behaviour-clone H3 into NAM's policy network, then fine-tune it with A2C.

Is H3 ("go to the nearest food you can load alone", ``transam.partners.lbf.heuristic``)
representable and learnable by the network NAM trains, from what it sees, and does A2C keep it?
Everything is the archived 3M NAM run's setting (docs/results/lbf/learnability/nam/config.json:
the LSTM policy, the time feature, NAM's one-hot previous action as z), the default game and
the default learned partner population; one seed.

    python docs/results/scripts/lbf_imitation.py clone runs/lbf-bc [--episodes 4000] [--steps 3000]
    python docs/results/scripts/lbf_imitation.py finetune runs/lbf-bc --variant a|b
    python docs/results/scripts/lbf_imitation.py evaluate runs/lbf-bc/a [--episodes 500]
    python docs/results/scripts/lbf_imitation.py clone runs/lbf-dagger \
        --init runs/lbf-bc/clone.msgpack --steps 0 --dagger 3 --dagger-steps 700
    python docs/results/scripts/lbf_imitation.py finetune runs/lbf-bc --variant b \
        --start-from b --name d-vf0 --a2c vf_coef=0 [--total-steps ... --every-steps ...]
    python docs/results/scripts/lbf_imitation.py advantages runs/lbf-bc/b [--checkpoint 0]

``clone`` plays H3 as the controlled agent (one episode per parallel copy, partners balanced
over the population as ``transam evaluate`` does; a training set and a separate validation
set), and trains the policy's actor path (LSTM trunk and action head; the critic head gets no
gradient) by cross-entropy on H3's actions over whole episodes: ``Policy.unroll`` from the
zero carry on each episode's own inputs, exactly as acting computes them. It writes
``clone.msgpack`` (the policy parameters) and ``clone.json`` (the learning curve: loss and
teacher-forced agreement with H3 on the validation episodes).

``--dagger R`` adds R rounds of DAgger: the clone plays ``--episodes`` episodes of its own
(sampled), H3's action on each of their steps is added to the data as the label, and training
goes on for ``--dagger-steps``; ``--init`` starts from saved clone parameters.

``finetune`` makes a run directory ``OUT/VARIANT`` with the trainer's own files: the runner
state of a fresh run (``init_runner`` through the trainer's compiled ``init``, seed 0) with
the clone's policy parameters, saved as the checkpoint of chunk 0; the trainer (``train``, the
archived config with ``total_steps``, an evaluation every ``--every-steps`` and every
checkpoint kept) then resumes from it, so chunk 0 is not trained by A2C. Variant ``a``: chunk
0 is the clone itself (critic head untrained, the return normaliser fresh). Variant ``b``:
chunk 0 is a critic warm-up, one chunk of the trainer's own updates in which the policy's
optimiser only receives the critic head's gradient (actor, LSTM and hidden layer frozen: the
critic is a linear read-out of the clone's features during the warm-up), which also warms the
return normaliser; the fine-tune then starts a fresh policy optimiser (Adam's moments of the
frozen parameters would be zero under an advanced step count, which makes the first actor
steps several times the learning rate), so in both variants A2C makes the same updates from
the learning rate 3e-4 annealed linearly over the run's ``total_steps``.

Diagnostics: ``--a2c KEY=VALUE`` changes an A2C setting of the fine-tune, ``--start-from RUN``
starts from that run's chunk 0 (e.g. b's warmed-up state), ``--name`` names the directory.
``advantages`` runs the trainer's own collections (``make_collect``) from a checkpoint with the
parameters held fixed and prints the advantage the update would use (normalised return target
minus the recomputed value) by the action taken: what the first updates reinforce.

``evaluate`` plays every checkpoint of a run (or ``--checkpoint N``) on ``--episodes``
episodes exactly as ``transam evaluate`` does (the same program's starts, partners and keys;
its returns are checked against that program's), sampled and greedy, and H3 on the same
episodes, and prints return ± standard error over episodes, the policy's entropy, and its
agreement with H3 on the states it visits itself: the share of steps where the policy's
argmax is H3's action, counted where H3 is deterministic (a food it can load alone is left;
otherwise H3 steps at random), and the mean probability the policy gives H3's action there.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import shutil
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import lbf_relative  # beside this script
import numpy as np
import optax
from flax import serialization
from lbf_behaviour import rule_agent

from transam.evaluation.final import balanced_partners, episodes_program
from transam.evaluation.weights import restore_weights
from transam.partners import lbf as lbf_partners
from transam.rundir import (
    checkpoints,
    load_run_config,
    read_checkpoint,
    save_checkpoint,
    start_run_dir,
)
from transam.train import a2c
from transam.train.a2c import act, batch_carry, env_step, first_step, make_policy, policy_entropy
from transam.train.config import TrainConfig
from transam.train.loop import train
from transam.train.programs import env_and_model, make_plan, program_key, run_programs

# A controlled agent: (carry, x, env_state, key) -> (carry, actions [n], extra outputs).
StepFn = Callable[[Any, Any, Any, jax.Array], tuple[Any, jax.Array, dict[str, jax.Array]]]


def run_config(out: str = "", total_steps: int = 1_100_000, every_steps: int = 100_000) -> Any:
    """The archived NAM run's config on the default game, one seed, every checkpoint kept."""
    config = lbf_relative.base_config(out, total_steps, env="lbf")
    every = every_steps // 50  # episodes of 50 steps
    return dataclasses.replace(
        config,
        num_seeds=1,
        seed=0,
        keep_checkpoints=0,
        eval=dataclasses.replace(config.eval, every_episodes=every),
    )


def h3_policy(config: TrainConfig) -> Callable[[jax.Array, jax.Array], jax.Array]:
    env, _ = env_and_model(config)
    return lbf_partners.heuristic(False, "own", env.game.config)


def h3_deterministic(env_state: Any) -> jax.Array:
    """[n] whether H3 acts by its rule (a food the controlled agent can load alone is left)."""
    game = env_state.game
    level = game.food_level
    return ((level > 0) & (level <= game.agent_level[:, :1])).any(-1)


def rollout(config: TrainConfig, n: int, key: jax.Array, step: StepFn, carry0: Any) -> Any:
    """n episodes, one per copy, partner i mod M, keyed as ``make_episodes`` keys them (so a
    policy's returns are those ``transam evaluate`` gives): per-step outputs [T, n]."""
    env, _ = env_and_model(config)
    partner = jnp.asarray(balanced_partners(n, env.num_partners))
    k_reset, k_run = jax.random.split(key)
    state0, obs = jax.vmap(env.reset)(jax.random.split(k_reset, n), partner)

    def body(carry: Any, key: jax.Array) -> Any:
        env_state, x, agent, alive = carry
        k_act, k_env = jax.random.split(key)
        det = h3_deterministic(env_state)
        agent, action, extra = step(agent, x, env_state, k_act)
        env_state, ts, x_next = env_step(env, k_env, env_state, action)
        live = alive.astype(jnp.float32)
        out = {"x": x, "action": action, "reward": ts.reward * live, "live": alive, "det": det}
        return (env_state, x_next, agent, alive & ~ts.done), {**out, **extra}

    init = (state0, first_step(obs), carry0, jnp.ones((n,), bool))
    keys = jax.random.split(k_run, env.spec.episode_len)
    return jax.lax.scan(body, init, keys)[1]


def h3_step(config: TrainConfig) -> tuple[StepFn, Callable[[int], Any]]:
    """H3 acting (lbf_behaviour's rule agent), recording the z NAM's model gives the policy."""
    env, model = env_and_model(config)
    _, rule = rule_agent(h3_policy(config))
    params = model.init(jax.random.key(0), env.spec)  # NAM: no parameters

    def step(mc: Any, x: Any, env_state: Any, key: jax.Array) -> Any:
        mc, z = a2c.model_step(model, params, mc, x, a2c.partner_view(model, env_state))
        _, action = rule((), x, env_state, key)
        return mc, action, {"z": z}

    return step, lambda n: batch_carry(model.init_carry(env.spec), n)


def policy_step(config: TrainConfig, policy_params: Any, model_params: Any, greedy: bool) -> Any:
    """The policy acting as in evaluation, with H3's action on the same observation beside it."""
    env, model = env_and_model(config)
    policy = make_policy(config, env)
    h3 = h3_policy(config)

    def step(carry: Any, x: Any, env_state: Any, key: jax.Array) -> Any:
        pc, mc = carry
        pc, mc, z, logits, _ = act(policy, model, policy_params, model_params, pc, mc, x, env_state)
        if greedy:
            action = jnp.argmax(logits, -1).astype(jnp.int32)
        else:
            action = jax.random.categorical(key, logits).astype(jnp.int32)
        n = action.shape[0]
        h3_action = jax.vmap(h3)(jax.random.split(jax.random.fold_in(key, 7), n), x.obs)
        probs = jax.nn.softmax(logits)
        extra = {
            "entropy": policy_entropy(logits),
            "agree": jnp.argmax(logits, -1) == h3_action,
            "p_h3": jnp.take_along_axis(probs, h3_action[:, None], -1)[:, 0],
            "h3": h3_action,
            "z": z,
        }
        return (pc, mc), action, extra

    def init(n: int) -> Any:
        return (policy.init_carry((n,)), batch_carry(model.init_carry(env.spec), n))

    return step, init


# ---------------------------------------------------------------- behaviour cloning


def demos(config: TrainConfig, n: int, seed: int) -> dict[str, Any]:
    step, init = h3_step(config)
    fn = jax.jit(lambda key: rollout(config, n, key, step, init(n)))
    return jax.device_get(fn(jax.random.key(seed)))


def clone(args: argparse.Namespace) -> None:
    config = run_config()
    env, _ = env_and_model(config)
    policy = make_policy(config, env)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tic = time.perf_counter()
    data = demos(config, args.episodes, seed=1)
    val = demos(config, 500, seed=2)
    ret = data["reward"].sum(0)
    print(
        f"H3 demonstrations: {args.episodes} episodes, return {ret.mean():.3f} ± "
        f"{ret.std() / np.sqrt(len(ret)):.3f}, {int(data['live'].sum())} steps "
        f"({time.perf_counter() - tic:.0f} s)",
        flush=True,
    )
    # The trainer's own fresh parameters for seed 0 (the runner state's, as finetune builds it)
    params = run_programs(config).init(jax.random.split(jax.random.key(0))[0]).policy_params
    if args.init:
        params = serialization.from_bytes(params, Path(args.init).read_bytes())
    tx = optax.chain(optax.clip_by_global_norm(1.0), optax.adam(args.lr))
    opt = tx.init(params)

    def loss_fn(params: Any, batch: dict[str, Any]) -> tuple[jax.Array, dict[str, jax.Array]]:
        b = batch["action"].shape[1]
        _, logits, _ = policy.unroll(params, policy.init_carry((b,)), batch["x"], batch["z"])
        nll = -jnp.take_along_axis(jax.nn.log_softmax(logits), batch["action"][..., None], -1)
        live = batch["live"].astype(jnp.float32)
        det = live * batch["det"]
        hit = jnp.argmax(logits, -1) == batch["action"]
        metrics = {
            "agree": (hit * live).sum() / live.sum(),
            "agree_det": (hit * det).sum() / det.sum(),
        }
        return (nll[..., 0] * live).sum() / live.sum(), metrics

    @jax.jit
    def train_step(params: Any, opt: Any, batch: dict[str, Any]) -> Any:
        (loss, _), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, batch)
        updates, opt = tx.update(grads, opt, params)
        return optax.apply_updates(params, updates), opt, loss

    score = jax.jit(loss_fn)
    rng = np.random.default_rng(0)
    curve: list[dict[str, Any]] = []

    def fit(params: Any, opt: Any, data: dict[str, Any], steps: int, start: int) -> Any:
        losses: list[float] = []
        for i in range(start, start + steps + 1):
            if i % args.log_every == 0 or i == start + steps:
                vloss, vm = jax.device_get(score(params, val))
                row = {"step": i, "train_loss": float(np.mean(losses)) if losses else None}
                row.update(val_loss=float(vloss), **{f"val_{k}": float(v) for k, v in vm.items()})
                curve.append(row)
                losses = []
                print(json.dumps(row), f"{time.perf_counter() - tic:.0f} s", flush=True)
            if i == start + steps:
                return params, opt
            n = data["action"].shape[1]
            idx = rng.choice(n, args.batch, replace=False)
            batch = jax.tree.map(lambda a, idx=idx: a[:, idx], data)
            params, opt, loss = train_step(params, opt, batch)
            losses.append(float(loss))
        return params, opt

    params, opt = fit(params, opt, data, args.steps, 0)
    done = args.steps
    for r in range(args.dagger):  # DAgger: H3's labels on the states the clone visits itself
        step, init = policy_step(config, params, {}, greedy=False)
        n = args.episodes
        fn = jax.jit(lambda key, step=step, init=init, n=n: rollout(config, n, key, step, init(n)))
        own = jax.device_get(fn(jax.random.key(10 + r)))
        ret, det = own["reward"].sum(0), own["live"] & own["det"]
        print(
            f"DAgger round {r + 1}: the clone's own {n} episodes, return {ret.mean():.3f} ± "
            f"{ret.std() / np.sqrt(n):.3f}, argmax = H3 on {own['agree'][det].mean():.3f} of "
            "the steps where H3 is deterministic",
            flush=True,
        )
        curve.append({"dagger_round": r + 1, "own_return": float(ret.mean())})
        keys = ("x", "z", "live", "det")
        new = {k: own[k] for k in keys} | {"action": own["h3"]}
        data = {k: data[k] for k in new}
        data = jax.tree.map(lambda a, b: np.concatenate([a, b], axis=1), data, new)
        params, opt = fit(params, opt, data, args.dagger_steps, done)
        done += args.dagger_steps
    (out / "clone.msgpack").write_bytes(serialization.to_bytes(params))
    settings = {k: v for k, v in vars(args).items() if k != "func"}
    (out / "clone.json").write_text(json.dumps({"settings": settings, "curve": curve}, indent=1))


# ---------------------------------------------------------------- A2C fine-tune


@contextlib.contextmanager
def critic_only() -> Iterator[None]:
    """While open, the trainer's updates (``make_update`` builds its optimisers with
    ``a2c.make_optimizers``) pass the policy optimiser only the critic head's gradient: the
    same optimiser and state (so its state is the trainer's), the other gradients zeroed."""
    original = a2c.make_optimizers

    def masked(config: TrainConfig) -> Any:
        policy_tx, model_tx = original(config)

        def keep_critic(grads: Any) -> Any:
            def one(path: Any, g: jax.Array) -> jax.Array:
                names = [getattr(k, "key", None) for k in path]
                return g if "critic" in names else jnp.zeros_like(g)

            return jax.tree_util.tree_map_with_path(one, grads)

        def update(grads: Any, state: Any, params: Any = None) -> Any:
            return policy_tx.update(keep_critic(grads), state, params)

        return optax.GradientTransformation(policy_tx.init, update), model_tx

    a2c.make_optimizers = masked
    try:
        yield
    finally:
        a2c.make_optimizers = original


def setting(current: Any, text: str) -> Any:
    """``text`` as a value of the type of the A2C setting it replaces."""
    if isinstance(current, bool):
        return text.lower() in ("1", "true", "yes")
    return type(current)(text)


def finetune(args: argparse.Namespace) -> None:
    run = Path(args.out) / (args.name or args.variant)
    config = run_config(str(run), args.total_steps, args.every_steps)
    changes = {k: setting(getattr(config.a2c, k), v) for k, v in (s.split("=") for s in args.a2c)}
    config = dataclasses.replace(config, a2c=dataclasses.replace(config.a2c, **changes))
    if args.start_from and not checkpoints(run):  # a diagnostic: another run's chunk 0
        start_run_dir(config)
        (run / "checkpoints").mkdir()
        shutil.copy(checkpoints(Path(args.out) / args.start_from)[0], run / "checkpoints")
    if not checkpoints(run):
        env, model = env_and_model(config)
        state = run_programs(config).init(jax.random.split(jax.random.key(config.seed))[0])
        cloned = serialization.from_bytes(
            state.policy_params, (Path(args.out) / "clone.msgpack").read_bytes()
        )
        policy_tx, _ = a2c.make_optimizers(config)
        state = dataclasses.replace(state, policy_params=cloned, policy_opt=policy_tx.init(cloned))
        if args.variant == "b":
            updates = make_plan(config, env.spec.episode_len).chunks[0]
            with critic_only():
                warmup = a2c.make_chunk(config, env, model, updates)
            tic = time.perf_counter()
            after, metrics = warmup(state)
            m = jax.device_get(metrics)
            before = jax.tree.leaves(
                jax.tree.map(jnp.array_equal, state.policy_params, after.policy_params)
            )
            print(
                f"critic warm-up: {updates} updates in {time.perf_counter() - tic:.0f} s, "
                f"value loss {float(m['value_loss']):.3f}, entropy {float(m['entropy']):.3f}, "
                f"return {float(m['return_sum']) / max(int(m['episodes']), 1):.3f}, "
                f"unchanged parameter arrays {sum(map(bool, before))}/{len(before)}",
                flush=True,
            )
            # A fresh optimiser for the fine-tune, as in variant a: Adam's moments of the frozen
            # parameters are still zero while its step count has advanced, so carried over they
            # would make the first actor steps several times the learning rate.
            state = dataclasses.replace(after, policy_opt=policy_tx.init(after.policy_params))
        start_run_dir(config)
        save_checkpoint(run, 0, jax.device_get(state))
    result = train(dataclasses.replace(config, resume=True))
    print(result.final)


# ---------------------------------------------------------------- evaluation


def mean_se(x: np.ndarray) -> str:
    return f"{x.mean():.3f} ± {x.std() / np.sqrt(len(x)):.3f}"


def evaluate(args: argparse.Namespace) -> None:
    run = Path(args.run)
    config = load_run_config(run)
    n = args.episodes
    key = jax.random.key(args.seed)
    found = sorted(checkpoints(run)) if args.checkpoint is None else [args.checkpoint]
    plays: dict[bool, Any] = {}

    def play(policy_params: Any, model_params: Any, greedy: bool) -> Any:
        step, init = policy_step(config, policy_params, model_params, greedy)
        return rollout(config, n, key, step, init(n))

    h3, h3_init = h3_step(config)
    h3_ret = jax.device_get(jax.jit(lambda: rollout(config, n, key, h3, h3_init(n)))())["reward"]
    print(f"{run}: {n} episodes, seed {args.seed}; H3 on them: {mean_se(h3_ret.sum(0))}")
    print(
        "chunk  step      sampled return   greedy return    entropy  agree(argmax=H3)  "
        "p(H3 action)  agree greedy"
    )
    rows = []
    for c in found:
        w = restore_weights(config, run, c, [])
        out = {}
        for greedy in (False, True):
            if greedy not in plays:
                plays[greedy] = jax.jit(lambda p, m, g=greedy: play(p, m, g))
            out[greedy] = jax.device_get(plays[greedy](w.policy_params, w.model_params))
        if c == found[0]:  # the same episodes as transam evaluate's program
            cfg = dataclasses.replace(config, eval=dataclasses.replace(config.eval, greedy=False))
            partner = jnp.asarray(balanced_partners(n, env_and_model(config)[0].num_partners))
            reference = episodes_program(program_key(cfg), n)
            ref = reference(w.policy_params, w.model_params, key, partner)
            ref_ret = np.asarray(jax.device_get(ref.reward)).sum(0)
            if not np.allclose(ref_ret, out[False]["reward"].sum(0), atol=1e-5):
                raise AssertionError("returns differ from transam evaluate's program")
        s, g = out[False], out[True]
        live = s["live"].astype(bool)
        det = live & s["det"]
        gdet = g["live"].astype(bool) & g["det"]
        row = {
            "chunk": c,
            "step": w.step,
            "return": s["reward"].sum(0),
            "greedy return": g["reward"].sum(0),
            "entropy": float(s["entropy"][live].mean()),
            "agree": float(s["agree"][det].mean()),
            "p_h3": float(s["p_h3"][det].mean()),
            "agree greedy": float(g["agree"][gdet].mean()),
            "det share": float(det.sum() / live.sum()),
        }
        rows.append(row)
        print(
            f"{c:5d}  {w.step:8d}  {mean_se(row['return']):>15s}  "
            f"{mean_se(row['greedy return']):>15s}  {row['entropy']:7.3f}  "
            f"{row['agree']:16.3f}  {row['p_h3']:12.3f}  {row['agree greedy']:12.3f}",
            flush=True,
        )
    summary = [
        {k: (float(v.mean()) if isinstance(v, np.ndarray) else v) for k, v in r.items()}
        | {"return_se": float(r["return"].std() / np.sqrt(n))}
        for r in rows
    ]
    (run / f"imitation_eval_{n}.json").write_text(json.dumps(summary, indent=1))


def advantages(args: argparse.Namespace) -> None:
    """What the first A2C update would reinforce: the trainer's own collections (``make_collect``,
    parameters held fixed) from a checkpoint, and the recomputed advantage (the normalised
    return target minus the critic's value, as the update computes it) by the action taken."""
    run = Path(args.run)
    config = load_run_config(run)
    env, model = env_and_model(config)
    policy = make_policy(config, env)
    template = run_programs(config).init(jax.random.key(0))
    state = read_checkpoint(checkpoints(run)[args.checkpoint], jax.device_get(template))
    collect = a2c.make_collect(config, env, model)
    per = config.a2c.rollouts_per_collect

    def one(rs: Any, key: jax.Array) -> Any:
        rs, col = collect(rs, jax.random.split(key, per))
        traj = col.traj

        def value(t: Any) -> jax.Array:
            return policy.unroll(rs.policy_params, t.policy_carry0, t.x, t.z)[2]

        adv = col.targets - jax.vmap(value)(traj)
        return rs, (adv, traj.action, traj.reward)

    keys = jax.random.split(jax.random.key(args.seed), args.collections)
    _, (adv, action, reward) = jax.device_get(jax.jit(lambda s: jax.lax.scan(one, s, keys))(state))
    adv, action, reward = (np.asarray(a).ravel() for a in (adv, action, reward))
    names = ("none", "north", "south", "west", "east")
    groups = [(n, action == i) for i, n in enumerate(names)]
    groups += [("load, collected", (action == 5) & (reward > 0))]
    groups += [("load, nothing", (action == 5) & (reward <= 0))]
    print(f"{run} chunk {args.checkpoint}: {adv.size} steps; mean advantage {adv.mean():+.3f}")
    for name, sel in groups:
        a = adv[sel]
        print(f"  {name:16s} {sel.mean():6.3f} of steps, advantage {mean_se(a)}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("clone")
    c.add_argument("out")
    c.add_argument("--episodes", type=int, default=4000)
    c.add_argument("--steps", type=int, default=3000)
    c.add_argument("--batch", type=int, default=64)
    c.add_argument("--lr", type=float, default=1e-3)
    c.add_argument("--log-every", type=int, default=250)
    c.add_argument("--init", default=None, help="start from these clone parameters")
    c.add_argument("--dagger", type=int, default=0, help="DAgger rounds after the cloning")
    c.add_argument("--dagger-steps", type=int, default=800, help="training steps per round")
    c.set_defaults(func=clone)
    f = sub.add_parser("finetune")
    f.add_argument("out", help="the directory clone wrote into")
    f.add_argument("--variant", choices=("a", "b"), required=True)
    f.add_argument("--total-steps", type=int, default=1_100_000)
    f.add_argument("--every-steps", type=int, default=100_000)
    f.add_argument("--name", default=None, help="run directory OUT/NAME (default: the variant)")
    f.add_argument("--a2c", action="append", default=[], help="a diagnostic: KEY=VALUE")
    f.add_argument("--start-from", default=None, help="a diagnostic: start from OUT/RUN's chunk 0")
    f.set_defaults(func=finetune)
    e = sub.add_parser("evaluate")
    e.add_argument("run")
    e.add_argument("--episodes", type=int, default=500)
    e.add_argument("--checkpoint", type=int, default=None)
    e.add_argument("--seed", type=int, default=0)
    e.set_defaults(func=evaluate)
    v = sub.add_parser("advantages")
    v.add_argument("run")
    v.add_argument("--checkpoint", type=int, default=0)
    v.add_argument("--collections", type=int, default=400)
    v.add_argument("--seed", type=int, default=0)
    v.set_defaults(func=advantages)
    args = parser.parse_args(argv)
    args.func(args)


if __name__ == "__main__":
    main()
