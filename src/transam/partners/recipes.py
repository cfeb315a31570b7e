"""Recipes of the learned partner populations, and the teams built from them.

A *family* is one compiled training program (game view + stand-in + static PPO settings); a
*run* is one vmapped lane of it (seed, discount, shaping); a run yields one member per
(checkpoint, agent) it names. The held-out population of each environment is built the same
way from other seeds (and, where the spec allows, other variants), never used in training.
Tag is the exception: its default population is LIAM's predators (imported, :data:`IMPORTED`)
and its held-out one is ours.

Budgets are kept small (2 shared CPU cores). Overcooked and LBF: the shortest that gave
partners clearly better than random on their own objective. Tag and Spread: about where the
learners' returns level off (Spread: the greedy self-play return of every run at 1/3, 2/3 and
all of the budget is in the manifest, ``checkpoint_returns``; Tag's MAPPO predators reach the
random prey 3.5x as often at 750k steps as at 150k). Numbers in each manifest.

A family's ``act`` is how its members pick actions when they play (``"sample"`` from the
softmax, or ``"argmax"``); it is written into each member's manifest entry, and the self-play
returns there are measured playing that way.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from transam import registry
from transam.partners.tag import LIAM_TABLE
from transam.partners.train import PPOConfig

ONION_ONLY = (3.0, 0.0, 0.0)  # (onion into pot, useful plate pickup, soup pickup)
DISH_ONLY = (0.0, 3.0, 5.0)
FULL = (3.0, 3.0, 5.0)


@dataclass(frozen=True)
class Family:
    """One compiled program: which stand-in plays the controlled slot, and the PPO settings."""

    name: str
    ppo: PPOConfig
    stand_in: str = "self-play"  # Tag: "flee" or "random" prey
    act: str = "sample"  # how the members play: "sample" (softmax) or "argmax" (greedy)


@dataclass(frozen=True)
class Run:
    """One training lane and the members taken from it: (name, checkpoint index, agent)."""

    family: str
    seed: int
    gamma: float
    members: tuple[tuple[str, int, int], ...]
    shaping: tuple[tuple[float, float, float], ...] | None = None  # per agent (Overcooked)
    shaping_label: str = "none"
    pick: bool = False  # Spread: members' agents chosen after training (learned.train_recipe)


@dataclass(frozen=True)
class Recipe:
    """A whole population's learned members (``teams`` mix them with heuristics)."""

    env: str
    split: str  # "default" or "heldout"
    families: tuple[Family, ...]
    runs: tuple[Run, ...]
    teams: tuple[tuple[str, tuple[str, ...]], ...]  # (team name, member per partner slot)

    def family(self, name: str) -> Family:
        return next(f for f in self.families if f.name == name)

    def scaled(self, total_steps: int, num_envs: int = 4, rollout_len: int = 8) -> Recipe:
        """The same recipe on a tiny budget (tests, smoke runs)."""
        fams = tuple(
            replace(
                f,
                ppo=replace(
                    f.ppo, total_steps=total_steps, num_envs=num_envs, rollout_len=rollout_len
                ),
            )
            for f in self.families
        )
        return replace(self, families=fams)


# ---------------------------------------------------------------------------------- Tag
TAG_PPO = PPOConfig(total_steps=750_000, num_envs=32, rollout_len=50)


def tag_recipe(split: str) -> Recipe:
    """Tag's held-out population: six learned predators, rl_a0-2 (IPPO vs a fleeing prey, with a
    5x entropy bonus: loose, stochastic chasers) and rl_b0-2 (MAPPO vs a random prey: tight
    chasers), in LIAM's 10-team table where LIAM has its IA2C (rl_a<i>) and MADDPG (rl_b<i>)
    agent i. The default population is LIAM's own predators, imported (:data:`IMPORTED`).

    These six were Tag's default population before LIAM's replaced it (same seeds, same
    weights). Why the entropy bonus: with the default bonus both families end up chasing like
    LIAM's ``after_prey`` heuristic, and a classifier tells the 10 teams apart from the
    predators' data only 21% of the time (chance 10%, LIAM's all-heuristic table 22%); with it,
    35%."""
    if split == "default":
        raise ValueError(IMPORTED[("tag", "default")])
    seed = 0
    fams = (
        Family("ippo-flee", replace(TAG_PPO, ent_coef=0.05), stand_in="flee"),
        Family("mappo-random", replace(TAG_PPO, algorithm="mappo"), stand_in="random"),
    )
    runs = (
        Run("ippo-flee", seed, 0.95, tuple((f"rl_a{i}", 0, i) for i in range(3))),
        Run("mappo-random", seed + 1, 0.95, tuple((f"rl_b{i}", 0, i) for i in range(3))),
    )
    teams = tuple((f"liam{i}", row) for i, row in enumerate(LIAM_TABLE))
    return Recipe("tag", split, fams, runs, teams)


# ------------------------------------------------------------------------------- Spread
SPREAD_PPO = PPOConfig(total_steps=1_200_000, num_envs=32, rollout_len=25, checkpoints=3)

SPREAD_HEURISTICS = (
    "after_first_landmark",
    "after_second_landmark",
    "after_third_landmark",
    "after_farthest_landmark",
    "after_closest_landmark",
)
"""The authors' five rules (:data:`transam.partners.spread.AUTHORS_HEURISTICS`), in their order."""


def spread_teams(heuristics: tuple[str, ...]) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """The authors' executed 13-team table (``pretrained_spread_opponents.py``, see
    ``reference/authors-spread/README.md``) with our members in their places: ``heuristics``
    fills their five heuristic places in order (first, second, third, farthest, closest there),
    ``ippo_k`` / ``mappo_k`` fill their ``ippo_k`` / ``mappo_k``.

    9 heuristic + learned teams (heuristics 0-4 in slot 0, heuristics 0-3 again in slot 1) and 4
    learned + learned ones; no team of two heuristics. Each learned member plays the slot of the
    agent it was trained as (even k: agent 0, odd k: agent 1), as in their table."""
    h = heuristics
    rows = (
        (h[0], "ippo_1"),
        (h[1], "mappo_1"),
        (h[2], "ippo_3"),
        (h[3], "mappo_3"),
        (h[4], "ippo_1"),
        ("ippo_0", h[0]),
        ("mappo_0", h[1]),
        ("ippo_2", h[2]),
        ("mappo_2", h[3]),
        ("ippo_0", "mappo_1"),
        ("ippo_2", "mappo_3"),
        ("mappo_0", "ippo_1"),
        ("mappo_2", "ippo_3"),
    )
    return tuple((f"{a}+{b}", (a, b)) for a, b in rows)


def spread_recipe(split: str) -> Recipe:
    """The authors' population structure on our trainer: eight greedy (``act: argmax``, as
    their actors) MLP actors, ``ippo_0-3`` from two IPPO self-play runs and ``mappo_0-3`` from
    two MAPPO runs (two of the three agents of each run, see ``pick``; final checkpoint of
    1.2M steps), in the authors' 13-team table
    with their five heuristics (:func:`spread_teams`).

    The held-out split: other seeds, and the heuristics rotated by one place (second, third,
    farthest, closest, first), so each heuristic meets other learned partners.

    Why ``pick``: self-play with one net per agent often leaves one agent *lazy*: it learns to
    run off in a fixed direction (out of the way, no collisions) while the other two cover two
    landmarks. Its team still scores well (-51 against random play's -71), but as a partner it
    is useless (greedy: a random controlled agent does worse beside it than beside a random
    partner). Every one of the eight runs of both splits had one such agent (agent 1 or 2).
    Each run therefore ships the two of its three agents beside which a random controlled agent
    does best (two copies of the agent as partners, played greedily), in index order; the
    manifest's ``agent_pick`` has the numbers, each member's ``agent`` the one taken."""
    seed = 0 if split == "default" else 100
    ppo = SPREAD_PPO
    fams = (
        Family("ippo", ppo, act="argmax"),
        Family("mappo", replace(ppo, algorithm="mappo"), act="argmax"),
    )
    last = ppo.checkpoints - 1
    runs = tuple(
        Run(
            algo,
            seed + 2 * i + j,
            0.99,
            tuple((f"{algo}_{2 * j + a}", last, a) for a in (0, 1)),
            pick=True,
        )
        for i, algo in enumerate(("ippo", "mappo"))
        for j in (0, 1)
    )
    heuristics = (
        SPREAD_HEURISTICS if split == "default" else (*SPREAD_HEURISTICS[1:], SPREAD_HEURISTICS[0])
    )
    return Recipe("spread", split, fams, runs, spread_teams(heuristics))


# --------------------------------------------------------------------------- Overcooked
OVERCOOKED_PPO = PPOConfig(total_steps=160_000, num_envs=16, rollout_len=100, ent_coef=0.02)


def overcooked_recipe(split: str) -> Recipe:
    """8 PPO partners (agent_1; agent_0 is the self-play stand-in): onion specialists (shaped
    only for onions, their training partner only for plates and soups), dish specialists (the
    reverse) and generalists (both cooks fully shaped), over seeds.

    The paper's draft also names "unshaped agents": unshaped PPO (sparse soup reward only)
    delivered no soup at 160k or 320k steps (2 seeds), so the non-specialists keep every
    shaping term."""
    base = 0 if split == "default" else 100
    kinds = (
        ("onion", (DISH_ONLY, ONION_ONLY)),
        ("dish", (ONION_ONLY, DISH_ONLY)),
        ("generalist", (FULL, FULL)),
    )
    counts = (
        {"onion": 3, "dish": 3, "generalist": 2}
        if split == "default"
        else {"onion": 2, "dish": 2, "generalist": 2}
    )
    runs: list[Run] = []
    for label, shaping in kinds:
        for s in range(counts[label]):
            name = f"{label}{s}"
            runs.append(
                Run("ippo", base + 10 * s + len(runs), 0.99, ((name, 0, 1),), shaping, label)
            )
    teams = tuple((r.members[0][0], (r.members[0][0],)) for r in runs)
    return Recipe("overcooked", split, (Family("ippo", OVERCOOKED_PPO),), tuple(runs), teams)


# ---------------------------------------------------------------------------------- LBF
LBF_PPO = PPOConfig(total_steps=160_000, num_envs=32, rollout_len=50, lr=1e-3, ent_coef=0.01)


def lbf_recipe(split: str) -> Recipe:
    """10 members from IPPO and MAPPO self-play pairs over seeds and discounts (0.99 down to
    0.5: the low ones are myopic); both agents of a run become members (the observation is
    observer-relative, so either net fits the partner slot)."""
    base = 0 if split == "default" else 100
    fams = (Family("ippo", LBF_PPO), Family("mappo", replace(LBF_PPO, algorithm="mappo")))
    plan = (
        (("ippo", 0.99), ("ippo", 0.9), ("ippo", 0.5), ("mappo", 0.99), ("mappo", 0.7))
        if split == "default"
        else (("ippo", 0.95), ("mappo", 0.8), ("mappo", 0.5))
    )
    runs: list[Run] = []
    for i, (algo, gamma) in enumerate(plan):
        tag = f"{algo}_g{round(gamma * 100):02d}"
        runs.append(Run(algo, base + i, gamma, ((f"{tag}_a0", 0, 0), (f"{tag}_a1", 0, 1))))
    learned = [m[0] for r in runs for m in r.members]
    extra = ("H1", "H3") if split == "heldout" else ()
    teams = tuple((n, (n,)) for n in (*learned, *extra))
    return Recipe("lbf", split, fams, tuple(runs), teams)


IMPORTED: dict[tuple[str, str], str] = {
    ("tag", "default"): (
        "Tag's default population is LIAM's pretrained predators, imported, not trained: "
        "`transam partners import-liam tag DIR` converts them; `transam partners train tag "
        "--heldout` trains ours (the held-out population)"
    ),
}
"""(env, split) populations converted from elsewhere rather than trained from a recipe."""


def recipe(env: str, heldout: bool = False) -> Recipe:
    """The recipe of ``env``'s default (or held-out) learned population; an imported split
    (:data:`IMPORTED`) has none and raises ValueError saying how it is made."""
    build = registry.resolve(registry.env_entry(env).recipe)
    if build is None:
        raise ValueError(f"environment {env!r} has no learned-population recipe (registry)")
    recipe: Recipe = build("heldout" if heldout else "default")
    return recipe
