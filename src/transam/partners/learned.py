"""Train, ship and load the learned partner populations (weights + manifest per environment).

Layout: ``transam/partners/data/<env>/manifest.json`` holds, per split (``default`` and
``heldout``), the member table (name, kind, recipe, seed, shaping, gamma, steps, agent,
checkpoint, action selection ``act``, self-play return played that way; Spread also each
member's scores of :func:`transam.partners.spread.member_scores`) and the teams;
``<split>.safetensors`` holds each member's actor as ``<member>/<param path>`` tensors.
Loading reads these files only: no network, no training.

An imported split (Tag's default: LIAM's predators, :mod:`transam.partners.liam`) has a
``source`` entry (repository, commit, licence) instead of training metadata; its members name
their ``arch`` and ``act``, and have no seed, stand-in or self-play return.

A **population directory** (``make_env(env, partners=DIR)``, ``--partners DIR``) has the same
format, one split: ``DIR/manifest.json`` with ``env``, the ``default`` split's entry (members
and teams) and optionally ``config`` (the env config fields it was made for, e.g.
``{"dynamics": "authors"}``) and ``name``; ``DIR/default.safetensors`` holds the weights.
Each member names ``name``, ``kind``, ``recipe``, ``arch`` (:data:`ARCHITECTURES`), ``act``
(``sample`` | ``argmax``) and what its architecture needs (``mlp``: ``hidden``); each team
``name`` and ``slots`` (member names, learned or from the env's heuristic pool, slot i driving
the i-th partner). ``transam partners import-authors`` writes one.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax.traverse_util import flatten_dict, unflatten_dict
from safetensors.numpy import load_file, save_file

from transam import registry
from transam.envs.core import EnvError
from transam.envs.joint import JointView, play
from transam.envs.population import Member, PolicyFn, Population, Team
from transam.partners import liam
from transam.partners.authors import ARCH as AUTHORS_ARCH
from transam.partners.authors import authors_logits
from transam.partners.recipes import Recipe
from transam.partners.train import (
    ACT_MODES,
    LogitsFn,
    make_logits,
    make_policy,
    select,
    select_probs,
    train_many,
)

SPLITS = ("default", "heldout")
EVAL_EPISODES = 32
DIR_SPLIT = "default"
"""The split a population directory holds (``manifest.json``'s entry, ``default.safetensors``)."""
SCORE_EPISODES = 128  # Spread: per number of spread.member_scores


def data_dir(env: str) -> Path:
    """The package folder holding ``env``'s shipped population."""
    return Path(str(resources.files("transam.partners"))) / "data" / env


def joint_view(env: str, stand_in: str = "self-play", tag_score: str = "shaped") -> JointView:
    """The training view of ``env`` with its default config (Tag: the named prey stand-in,
    scored by ``tag_score``, see :func:`transam.partners.tag.joint_view`), from its partners
    module (its registry entry's ``partners``)."""
    view: JointView = _partners_module(env).joint_view(stand_in, tag_score)
    return view


def _partners_module(env: str) -> Any:
    module = registry.resolve(registry.env_entry(env).partners)
    if module is None:
        raise ValueError(f"environment {env!r} has no partners module (its registry entry)")
    return module


def random_policy(num_actions: int) -> PolicyFn:
    def act(key: jax.Array, obs: jax.Array) -> jax.Array:
        del obs
        return jax.random.randint(key, (), 0, num_actions, dtype=jnp.int32)

    return act


def evaluate(
    view: JointView, policies: list[PolicyFn], seed: int = 0, weights: Any = None
) -> np.ndarray:
    """Mean episode score per learner over EVAL_EPISODES episodes (jitted)."""
    fn = jax.jit(lambda k: play(view, policies, k, EVAL_EPISODES, weights)[0])
    return np.asarray(fn(jax.random.PRNGKey(seed)))


MEASURE_PREY = "random"
"""The Tag prey that plays against a member with no training stand-in (an imported one)."""


def stand_in_of(member: dict[str, Any]) -> str:
    """The stand-in a manifest member is measured against: its training one, else
    :data:`MEASURE_PREY` (LIAM's predators trained against LIAM's own prey, not shipped)."""
    return str(member.get("stand_in", MEASURE_PREY))


def measure_members(
    env: str,
    rows: list[dict],
    members: dict,
    episodes: int,
    tag_score: str = "shaped",
    with_random: bool = False,
) -> dict[str, float]:
    """Mean score with every learner slot played by one member (one program per stand-in);
    ``with_random`` adds uniformly random players as ``random/<stand-in>``."""
    out: dict[str, float] = {}
    for stand_in in sorted({stand_in_of(m) for m in rows}):
        names = [m["name"] for m in rows if stand_in_of(m) == stand_in]
        acts = [members[n].act for n in names]
        view = joint_view(env, stand_in, tag_score)
        if with_random:
            names.append(f"random/{stand_in}")
            acts.append(random_policy(view.num_actions))

        def score(idx: jax.Array, acts: list = acts, view: JointView = view) -> jax.Array:
            pol = lambda k, o: jax.lax.switch(idx, acts, k, o)
            key = jax.random.PRNGKey(1)
            return jnp.mean(play(view, [pol] * view.num_agents, key, episodes)[0])

        vals = jax.jit(jax.vmap(score))(jnp.arange(len(names)))
        out.update({n: float(v) for n, v in zip(names, vals, strict=True)})
    return out


def train_recipe(recipe: Recipe, log: Any = print) -> tuple[dict[str, np.ndarray], dict]:
    """Train every run of ``recipe`` (one vmapped program per family) and score the results.

    Returns (safetensors dict, manifest split entry). Deterministic for a given recipe.
    """
    tensors: dict[str, np.ndarray] = {}
    members: list[dict[str, Any]] = []
    random_returns: dict[str, list[float]] = {}
    checkpoint_returns: dict[str, list[list[float]]] = {}
    agent_pick: dict[str, dict[str, list]] = {}
    acting: dict[str, tuple[PolicyFn, int]] = {}  # member -> (act as shipped, its slot)
    for fam in recipe.families:
        runs = [r for r in recipe.runs if r.family == fam.name]
        if not runs:
            continue
        view = joint_view(recipe.env, fam.stand_in)
        weights = [
            np.asarray(r.shaping if r.shaping else np.zeros((view.num_agents, 3)), np.float32)
            for r in runs
        ]
        t0 = time.time()
        params, _ = train_many(
            view, fam.ppo, [r.seed for r in runs], [r.gamma for r in runs], weights
        )
        secs = time.time() - t0
        log(f"{recipe.env}/{recipe.split} {fam.name}: {len(runs)} run(s) in {secs:.1f}s")
        rnd = evaluate(view, [random_policy(view.num_actions)] * view.num_agents)
        random_returns[fam.stand_in] = [round(float(x), 4) for x in rnd]

        def team(p: Any, fam: Any = fam, view: JointView = view) -> list[PolicyFn]:
            """The run's learners at one checkpoint, acting as the family's members do."""
            return [
                make_policy(
                    jax.tree.map(lambda leaf, a=a: leaf[a], p),
                    recipe.env,
                    view.num_actions,
                    fam.ppo.hidden,
                    fam.act,
                )
                for a in range(view.num_agents)
            ]

        # Every checkpoint of a run in one program (one compilation per family): [K, A] scores.
        curve_fn = jax.jit(
            jax.vmap(
                lambda p, team=team, view=view: play(
                    view, team(p), jax.random.PRNGKey(0), EVAL_EPISODES
                )[0]
            )
        )
        for i, run in enumerate(runs):
            run_p = jax.tree.map(lambda x, i=i: x[i], params)  # [K, A, ...]
            curve = [[round(float(x), 4) for x in row] for row in np.asarray(curve_fn(run_p))]
            label = f"{fam.name}/seed{run.seed}"
            if fam.ppo.checkpoints > 1:  # the learning curve, played as the members play
                checkpoint_returns[label] = curve
            run_members = run.members
            if run.pick:  # the best agents of the run, in index order (recipes.spread_recipe)
                from transam.partners.spread import agent_ranks

                ck = run.members[0][1]
                ranks = agent_ranks(view, team(jax.tree.map(lambda x, c=ck: x[c], run_p)))
                best = sorted(
                    sorted(range(view.num_agents), key=lambda a: -ranks[a])[: len(run_members)]
                )
                run_members = tuple((n, c, best[k]) for k, (n, c, _) in enumerate(run_members))
                agent_pick[label] = {"ranks": ranks, "agents": best}
                log(f"{recipe.env}/{recipe.split} {label}: agents {best} (ranks {ranks})")
            for slot, (name, ck, agent) in enumerate(run_members):
                p = jax.tree.map(lambda x, c=ck, a=agent: np.asarray(x[c, a]), run_p)
                for path, arr in flatten_dict(p, sep="/").items():
                    tensors[f"{name}/{path}"] = np.ascontiguousarray(arr, np.float32)
                acting[name] = (  # Spread: the k-th member of a run plays partner slot k
                    make_policy(p, recipe.env, view.num_actions, fam.ppo.hidden, fam.act),
                    slot,
                )
                steps = fam.ppo.num_updates * fam.ppo.num_envs * fam.ppo.rollout_len
                members.append(
                    {
                        "name": name,
                        "kind": fam.ppo.algorithm,
                        "recipe": fam.name,
                        "stand_in": fam.stand_in,
                        "act": fam.act,
                        "seed": run.seed,
                        "shaping": run.shaping_label,
                        "shaping_weights": [list(w) for w in run.shaping] if run.shaping else None,
                        "gamma": run.gamma,
                        "steps": steps * (ck + 1) // fam.ppo.checkpoints,
                        "agent": agent,
                        "checkpoint": ck,
                        "hidden": fam.ppo.hidden,
                        "self_play_return": curve[ck][agent],
                        "self_play_returns_all": curve[ck],
                        "train_seconds": round(secs / len(runs), 1),
                    }
                )
    entry: dict[str, Any] = {
        "members": members,
        "teams": [{"name": n, "slots": list(s)} for n, s in recipe.teams],
        "random_return": random_returns,
        "eval_episodes": EVAL_EPISODES,
    }
    if checkpoint_returns:
        entry["checkpoint_returns"] = checkpoint_returns
    if agent_pick:
        entry["agent_pick"] = agent_pick
    if recipe.env == "spread":
        from transam.partners.spread import member_scores

        t0 = time.time()
        found, baseline = member_scores(joint_view("spread"), acting, SCORE_EPISODES)
        log(f"spread/{recipe.split}: member scores in {time.time() - t0:.1f}s")
        for m in members:
            m.update(found[m["name"]])
        entry["random_controlled_baseline"] = baseline
        entry["score_episodes"] = SCORE_EPISODES
    return tensors, entry


def rescore(env: str, split: str = "default", root: Path | None = None) -> dict:
    """Recompute the manifest's self-play and random returns from the shipped weights.

    Only for games whose every learner of a run is shipped (Tag, LBF); the others need the
    unshipped self-play stand-in and keep their training-time numbers.
    """
    manifest = load_manifest(env, root)
    entry = manifest[split]
    if "source" in entry:
        raise ValueError(f"{env}/{split} is imported from {entry['source']['repository']}: no runs")
    members = learned_members(env, split, root)
    runs: dict[tuple, dict[int, str]] = {}
    for m in entry["members"]:
        runs.setdefault((m["recipe"], m["seed"], m["checkpoint"]), {})[m["agent"]] = m["name"]
    done: set[str] = set()
    for m in entry["members"]:
        view = joint_view(env, m["stand_in"])
        team = runs[(m["recipe"], m["seed"], m["checkpoint"])]
        if len(team) < view.num_agents:
            raise ValueError(f"{env}: run of {m['name']} is not fully shipped; cannot rescore")
        pols = [members[team[a]].act for a in range(view.num_agents)]
        m["self_play_return"] = round(float(evaluate(view, pols)[m["agent"]]), 4)
        if m["stand_in"] not in done:
            rnd = evaluate(view, [random_policy(view.num_actions)] * view.num_agents)
            entry["random_return"][m["stand_in"]] = [round(float(x), 4) for x in rnd]
            done.add(m["stand_in"])
    write_manifest(env, manifest, root)
    return entry


def write_manifest(env: str, manifest: dict, root: Path | None = None) -> Path:
    """Replace ``env``'s manifest atomically (temp file, then rename)."""
    path = (root or data_dir(env)) / "manifest.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    tmp.replace(path)
    return path


def record_diversity(env: str, split: str, found: dict, root: Path | None = None) -> None:
    """Store a ``transam partners diversity`` measurement in ``split``'s manifest entry (a
    retrained split drops it: :func:`save` writes a fresh entry)."""
    manifest = load_manifest(env, root)
    manifest[split]["diversity"] = found
    write_manifest(env, manifest, root)


def save(
    env: str, split: str, tensors: dict[str, np.ndarray], entry: dict, root: Path | None = None
) -> Path:
    """Write ``split``'s weights and its manifest entry (other splits kept)."""
    d = root or data_dir(env)
    d.mkdir(parents=True, exist_ok=True)
    # Temp file then rename, so an interrupted save never leaves half-written shipped data.
    weights = d / f"{split}.safetensors"
    save_file(tensors, str(weights.with_suffix(".tmp")))
    weights.with_suffix(".tmp").chmod(0o644)  # safetensors writes 0600; ship readable
    weights.with_suffix(".tmp").replace(weights)
    path = d / "manifest.json"
    manifest = json.loads(path.read_text()) if path.exists() else {"env": env}
    manifest[split] = entry
    return write_manifest(env, manifest, root)


class ManifestError(EnvError):
    """A partner manifest that exists but cannot be read; the message names the file (a
    damaged manifest is an error, never read as "nothing recorded")."""


def load_manifest(env: str, root: Path | None = None) -> dict:
    """``env``'s shipped manifest (or the one under ``root``): FileNotFoundError where there is
    none, :class:`ManifestError` where it is not a JSON object."""
    path = (root or data_dir(env)) / "manifest.json"
    if not path.exists():
        raise FileNotFoundError(
            f"no shipped partners for {env!r} at {path}; run `transam partners train {env}`"
        )
    try:
        manifest = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ManifestError(f"partner manifest {path} is unreadable: {err}") from None
    if not isinstance(manifest, dict):
        raise ManifestError(f"partner manifest {path} is not a JSON object")
    return manifest


def load_params(env: str, split: str = "default", root: Path | None = None) -> dict[str, Any]:
    """Member name -> actor params (nested dict of numpy arrays)."""
    flat = load_file(str((root or data_dir(env)) / f"{split}.safetensors"))
    by_member: dict[str, dict[str, np.ndarray]] = {}
    for key, arr in flat.items():
        name, path = key.split("/", 1)
        by_member.setdefault(name, {})[path] = arr
    return {n: unflatten_dict(p, sep="/") for n, p in by_member.items()}


def digest(env: str, split: str = "default", root: Path | None = None) -> str:
    """A short fingerprint of what ``split``'s shipped population plays (its weights and team
    table, not the manifest's measurements): runs record it, so a retrained population is never
    mixed up with the one a run trained against."""
    d = root or data_dir(env)
    entry = load_manifest(env, root)[split]
    h = hashlib.sha256((d / f"{split}.safetensors").read_bytes())
    h.update(json.dumps(entry["teams"], sort_keys=True).encode())
    return h.hexdigest()[:16]


def is_population_dir(path: str | Path) -> bool:
    """Whether ``path`` is a population directory (it holds a ``manifest.json``)."""
    return Path(path).is_dir() and (Path(path) / "manifest.json").is_file()


def read_population_dir(path: str | Path, env: str | None = None) -> dict[str, Any]:
    """The manifest of population directory ``path`` (module doc), checked: it names ``env``
    (when given) and holds the ``default`` split's entry and weights."""
    d = Path(path)
    try:
        manifest = json.loads((d / "manifest.json").read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(
            f"population directory {str(d)!r}: unreadable manifest.json ({err})"
        ) from None
    if not isinstance(manifest, dict) or not isinstance(manifest.get(DIR_SPLIT), dict):
        raise ValueError(
            f"population directory {str(d)!r}: manifest.json has no {DIR_SPLIT!r} split entry"
        )
    if env is not None and manifest.get("env", env) != env:
        raise ValueError(
            f"population directory {str(d)!r} is for env {manifest['env']!r}, not {env!r}"
        )
    if not (d / f"{DIR_SPLIT}.safetensors").is_file():
        raise ValueError(f"population directory {str(d)!r}: {DIR_SPLIT}.safetensors missing")
    return manifest


def directory_digest(path: str | Path) -> str:
    """A fingerprint of what population directory ``path`` plays: its weights, its teams, how
    each member acts (name, arch, act, hidden) and the config it names."""
    d = Path(path)
    manifest = read_population_dir(d)
    entry = manifest[DIR_SPLIT]
    h = hashlib.sha256((d / f"{DIR_SPLIT}.safetensors").read_bytes())
    play = [
        {k: m.get(k) for k in ("name", "arch", "act", "hidden")} for m in entry.get("members", [])
    ]
    what = {"teams": entry.get("teams", []), "members": play, "config": manifest.get("config")}
    h.update(json.dumps(what, sort_keys=True).encode())
    return h.hexdigest()[:16]


def population_digest(env: str, partners: str) -> str | None:
    """The fingerprint of the population ``make_env(env, partners=partners)`` plays:
    :func:`digest` of a shipped split, :func:`directory_digest` of a population directory;
    None for one built by code (``"heuristic"``, a registry entry's ``populations``)."""
    if partners in registry.env_entry(env).populations:
        return None
    if partners in SPLITS:
        return digest(env, partners)
    return directory_digest(partners)


MemberBuilder = Callable[[dict[str, Any], dict[str, Any], str], LogitsFn]
"""(member params, manifest member entry, env) -> the member's logits function."""


def _mlp_logits(params: dict[str, Any], entry: dict[str, Any], env: str) -> LogitsFn:
    return make_logits(params, env, registry.env_entry(env).partner_actions, entry["hidden"])


ARCHITECTURES: dict[str, MemberBuilder] = {
    "mlp": _mlp_logits,  # our IPPO/MAPPO actor (transam.partners.train.MLP)
    "liam-ia2c": liam.ia2c_logits,  # LIAM's IA2C Tag predators
    "liam-maddpg": liam.maddpg_logits,  # LIAM's MADDPG Tag predators (BatchNorm in eval mode)
    AUTHORS_ARCH: authors_logits,  # the TransAM authors' Spread actor (transam.partners.authors)
}
"""Network architectures a manifest member may name (``"arch"``, default ``"mlp"``)."""


def _member_logits(params: dict[str, Any], entry: dict[str, Any], env: str) -> LogitsFn:
    """A manifest member's logits function (its ``"arch"``, checked)."""
    arch = entry.get("arch", "mlp")
    if arch not in ARCHITECTURES:
        valid = ", ".join(ARCHITECTURES)
        raise ValueError(f"member {entry['name']!r}: unknown arch {arch!r}; valid choices: {valid}")
    return ARCHITECTURES[arch](params, entry, env)


def _member_act(entry: dict[str, Any]) -> str:
    """A manifest member's action selection (``"act"``, checked)."""
    act = str(entry.get("act", "sample"))
    if act not in ACT_MODES:
        valid = ", ".join(ACT_MODES)
        raise ValueError(f"member {entry['name']!r}: unknown act {act!r}; valid choices: {valid}")
    return act


def learned_member(params: dict[str, Any], entry: dict[str, Any], env: str) -> Member:
    """One manifest member as a population member: its architecture's logits (built once),
    acting by its action selection (``"act"``: ``"sample"`` (default) or ``"argmax"``), with
    the distribution it draws from (softmax, or a one-hot of the argmax) as ``probs``."""
    logits, act = _member_logits(params, entry, env), _member_act(entry)
    return Member(
        entry["name"],
        select(logits, act),
        kind=f"{entry['kind']}:{entry['recipe']}",
        probs=select_probs(logits, act),
    )


def member_policy(params: dict[str, Any], entry: dict[str, Any], env: str) -> PolicyFn:
    """The act function of one manifest member (:func:`learned_member`)."""
    return learned_member(params, entry, env).act


def learned_members(
    env: str, split: str = "default", root: Path | None = None
) -> dict[str, Member]:
    """The shipped learned members of ``env`` as population members, each acting as its
    manifest entry says (architecture and action selection)."""
    entry = load_manifest(env, root)[split]
    params = load_params(env, split, root)
    missing = [m["name"] for m in entry["members"] if m["name"] not in params]
    if missing:
        where = (root or data_dir(env)) / f"{split}.safetensors"
        raise ValueError(f"{where}: no weights for member(s) {', '.join(missing)}")
    return {m["name"]: learned_member(params[m["name"]], m, env) for m in entry["members"]}


def heuristic_pool(env: str) -> dict[str, Member]:
    """The environment's heuristic members, by name (none without a partners module)."""
    module = registry.resolve(registry.env_entry(env).partners)
    return {} if module is None else dict(module.heuristic_pool())


def population(
    env: str, split: str = "default", root: Path | None = None, name: str | None = None
) -> Population:
    """``env``'s shipped population (or, with ``root``, the one stored there): learned members
    plus the heuristics its teams name (from :func:`heuristic_pool`).

    """
    learned = learned_members(env, split, root)
    name = name or f"{env}-{split}"
    entry = load_manifest(env, root)[split]
    pool = {**heuristic_pool(env), **learned}
    teams = [Team(t["name"], tuple(t["slots"])) for t in entry["teams"]]
    if not teams:
        raise ValueError(f"population {name!r}: the manifest lists no teams")
    used = sorted({s for t in teams for s in t.slots})
    unknown = [n for n in used if n not in pool]
    if unknown:
        raise ValueError(
            f"population {name!r}: teams name unknown member(s) {', '.join(unknown)}; "
            f"known: {', '.join(pool)}"
        )
    return Population(name, [pool[n] for n in used], teams)


def directory_population(env: str, path: str | Path) -> Population:
    """The population stored in population directory ``path`` (module doc), for ``env``."""
    manifest = read_population_dir(path, env)
    name = manifest.get("name") or f"{env}-{Path(path).resolve().name}"
    return population(env, DIR_SPLIT, Path(path), name=name)
