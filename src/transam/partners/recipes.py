"""Recipes of the learned partner populations, and the teams built from them.

A *family* is one compiled training program (game view + stand-in + static PPO settings); a
*run* is one vmapped lane of it (seed, discount, shaping); a run yields one member per
(checkpoint, agent) it names. The held-out population of each environment is built the same
way from other seeds (and, where the spec allows, other variants), never used in training.
Tag is the exception: its default population is LIAM's predators (imported, :data:`IMPORTED`)
and its held-out one is ours.

Budgets are kept small (2 shared CPU cores). Overcooked and LBF: the shortest that gave
partners clearly better than random on their own objective. Tag and Spread: about where the
learners' returns level off (Spread's self-play returns gain under 2 points from 1.2M to 2M
steps; Tag's MAPPO predators reach the random prey 3.5x as often at 750k steps as at 150k).
Numbers in each manifest.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

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


@dataclass(frozen=True)
class Run:
    """One training lane and the members taken from it: (name, checkpoint index, agent)."""

    family: str
    seed: int
    gamma: float
    members: tuple[tuple[str, int, int], ...]
    shaping: tuple[tuple[float, float, float], ...] | None = None  # per agent (Overcooked)
    shaping_label: str = "none"


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


def _tag(split: str) -> Recipe:
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


def _spread(split: str) -> Recipe:
    """IPPO and MAPPO self-play triples, agents 0 and 1 kept at low / medium / high skill
    (checkpoints at 1/3, 2/3 and the end), mixed with the landmark heuristics."""
    seed = 0 if split == "default" else 100
    fams = (Family("ippo", SPREAD_PPO), Family("mappo", replace(SPREAD_PPO, algorithm="mappo")))
    levels = ("low", "medium", "high")

    def members(algo: str) -> tuple[tuple[str, int, int], ...]:
        return tuple((f"{algo}_{lv}_{a}", c, a) for c, lv in enumerate(levels) for a in (0, 1))

    runs = (
        Run("ippo", seed, 0.99, members("ippo")),
        Run("mappo", seed + 1, 0.99, members("mappo")),
    )
    teams: tuple[tuple[str, tuple[str, ...]], ...]
    if split == "default":
        teams = (
            ("first+second", ("first", "second")),
            ("third+first", ("third", "first")),
            ("second+second", ("second", "second")),
            ("closest+closest", ("closest", "closest")),
            ("farthest+first", ("farthest", "first")),
            ("ippo_low", ("ippo_low_0", "ippo_low_1")),
            ("ippo_medium", ("ippo_medium_0", "ippo_medium_1")),
            ("ippo_high", ("ippo_high_0", "ippo_high_1")),
            ("mappo_low", ("mappo_low_0", "mappo_low_1")),
            ("mappo_medium", ("mappo_medium_0", "mappo_medium_1")),
            ("mappo_high", ("mappo_high_0", "mappo_high_1")),
            ("ippo_high+mappo_low", ("ippo_high_0", "mappo_low_1")),
            ("first+ippo_medium", ("first", "ippo_medium_1")),
        )
    else:
        teams = (
            ("second+third", ("second", "third")),
            ("third+third", ("third", "third")),
            ("closest+farthest", ("closest", "farthest")),
            ("ippo_medium", ("ippo_medium_0", "ippo_medium_1")),
            ("ippo_high", ("ippo_high_0", "ippo_high_1")),
            ("mappo_medium", ("mappo_medium_0", "mappo_medium_1")),
            ("mappo_high", ("mappo_high_0", "mappo_high_1")),
            ("mappo_high+third", ("mappo_high_0", "third")),
        )
    return Recipe("spread", split, fams, runs, teams)


# --------------------------------------------------------------------------- Overcooked
OVERCOOKED_PPO = PPOConfig(total_steps=160_000, num_envs=16, rollout_len=100, ent_coef=0.02)


def _overcooked(split: str) -> Recipe:
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


def _lbf(split: str) -> Recipe:
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


BUILDERS = {"tag": _tag, "spread": _spread, "overcooked": _overcooked, "lbf": _lbf}

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
    if env not in BUILDERS:
        raise ValueError(f"unknown environment {env!r}; valid: {', '.join(BUILDERS)}")
    return BUILDERS[env]("heldout" if heldout else "default")
