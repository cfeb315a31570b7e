"""``transam partners ...`` subcommands (tyro dataclasses with a ``run`` method).

Wire into ``transam.cli`` as ``Annotated[Partners, tyro.conf.subcommand("partners")]``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro
from rich.console import Console
from rich.table import Table

from transam.registry import EnvName

console = Console()


def _split(heldout: bool) -> str:
    return "heldout" if heldout else "default"


@dataclass
class PartnersTrain:
    """Regenerate ENV's learned population from scratch (deterministic) into the package data."""

    env: tyro.conf.Positional[EnvName]
    heldout: bool = False  # train the held-out population instead of the default one
    steps: int | None = None  # smoke runs: every family gets this budget, 4 envs, 8-step rollouts
    out: Path | None = None  # write here instead of the package data (use with --steps)

    def run(self) -> None:
        from transam.partners import learned
        from transam.partners.recipes import recipe

        if self.steps is not None and self.out is None:
            raise SystemExit(
                "error: --steps changes the recipe's budget; pass --out DIR too, so the shipped "
                f"{self.env} population is not overwritten by a smoke run"
            )
        try:
            r = recipe(self.env, self.heldout)
        except ValueError as err:
            raise SystemExit(f"error: {err}") from None
        if self.steps is not None:
            r = r.scaled(self.steps)
        t0 = time.time()
        tensors, entry = learned.train_recipe(r, log=console.print)
        path = learned.save(self.env, r.split, tensors, entry, root=self.out)
        digest = learned.digest(self.env, r.split, root=self.out)
        console.print(
            f"trained {len(entry['members'])} members in {time.time() - t0:.1f}s -> {path} "
            f"(digest {digest})"
        )


@dataclass
class PartnersShow:
    """Print ENV's manifest with each member's measured return against its stand-in."""

    env: tyro.conf.Positional[EnvName]
    heldout: bool = False
    episodes: int = 128  # episodes per measured number

    def run(self) -> None:
        from transam.partners import learned

        if self.episodes < 1:
            raise SystemExit(f"error: --episodes must be at least 1, got {self.episodes}")
        split = _split(self.heldout)
        entry = learned.load_manifest(self.env)[split]
        members = learned.learned_members(self.env, split)
        measured = learned.measure_members(self.env, entry["members"], members, self.episodes)
        # Tag: also how often each team of three reaches the prey, and random predators' rate.
        touches = (
            learned.measure_members(
                self.env, entry["members"], members, self.episodes, "touches", True
            )
            if self.env == "tag"
            else {}
        )
        digest = learned.digest(self.env, split)
        table = Table(title=f"{self.env} {split} learned partners (digest {digest})")
        rows = [
            {
                "member": m["name"],
                "kind": m["kind"],
                "recipe": m["recipe"],
                "act": m.get("act", "sample"),
                # Imported members (LIAM's) have no training metadata: "-", column dropped.
                "seed": str(m.get("seed", "-")),
                "shaping": m.get("shaping", "-"),
                "gamma": f"{m['gamma']:g}" if "gamma" in m else "-",
                "steps": f"{m['steps']:,}" if "steps" in m else "-",
                "self-play": f"{m['self_play_return']:.3f}" if "self_play_return" in m else "-",
                "vs": learned.stand_in_of(m),
                "measured": f"{measured[m['name']]:.3f}",
                **({"touches": f"{touches[m['name']]:.2f}"} if touches else {}),
            }
            for m in entry["members"]
        ]
        cols = [c for c in rows[0] if any(r[c] != "-" for r in rows)]
        for c in cols:
            table.add_column(c, justify="left" if c in ("member", "recipe", "vs") else "right")
        for r in rows:
            table.add_row(*(r[c] for c in cols))
        console.print(table)
        if "source" in entry:
            src = entry["source"]
            licence = learned.data_dir(self.env) / src["license_file"]
            console.print(
                f"imported from {src['repository']}@{src['commit'][:8]} ({src['license']}, "
                f"{src['copyright']}; licence in {licence})"
            )
        if "random_return" in entry:
            console.print(f"random play: {entry['random_return']}")
        if touches:
            rnd = {k.split("/")[1]: round(v, 2) for k, v in touches.items() if "/" in k}
            console.print(
                f"touches: steps per episode with a predator within the capture distance of "
                f"the prey; random predators: {rnd}"
            )
        if entry["teams"]:
            console.print("teams: " + ", ".join(t["name"] for t in entry["teams"]))
        console.print(
            "self-play: the member's training run (manifest); measured: every learner slot "
            f"played by this member, against the stand-in in column vs ({self.episodes} "
            "episodes)"
        )


@dataclass
class PartnersDiversity:
    """Cross-play matrix (LBF, Overcooked), partner-index classifier accuracy vs chance, and the
    partners' action-accuracy levels: the ceiling E[max_a pi(a|o)] and the memoryless,
    team-agnostic level (an MLP from a partner's own observation, pooled over teams)."""

    env: tyro.conf.Positional[EnvName]
    heldout: bool = False
    heuristic: bool = False  # the scripted population (partners="heuristic") instead
    window: int = 10  # steps per classifier sample
    record: bool = False  # store the results in the shipped manifest (the README quotes it)

    def run(self) -> None:
        from rich.markup import escape

        from transam.compose import make_env
        from transam.partners import learned
        from transam.partners.diversity import (
            ClassifierConfig,
            LevelsConfig,
            action_levels,
            cross_play,
            partner_id_accuracy,
        )

        if self.heuristic and (self.heldout or self.record):
            raise SystemExit(
                "error: --heuristic measures the scripted population, which has no manifest "
                "entry: it takes neither --heldout nor --record"
            )
        split = "heuristic" if self.heuristic else _split(self.heldout)
        if self.heuristic:
            env = make_env(self.env, partners="heuristic")
        else:
            env = make_env(self.env, population=learned.population(self.env, split))
        if not 1 <= self.window <= env.spec.episode_len:
            raise SystemExit(
                f"error: --window must be between 1 and {self.env}'s episode length "
                f"{env.spec.episode_len} (a window stays inside one episode), got {self.window}"
            )
        if self.env in ("lbf", "overcooked") and not self.heuristic:
            members = learned.learned_members(self.env, split)
            names = list(members)
            mat = cross_play(self.env, [members[n] for n in names])
            table = Table(title=f"{self.env} cross-play (row: partner, column: stand-in slot)")
            table.add_column("partner", no_wrap=True)
            for j in range(len(names)):
                table.add_column(str(j), justify="right")
            for i, (n, row) in enumerate(zip(names, mat, strict=True)):
                table.add_row(f"{i} {n}", *(f"{x:.2f}" for x in row))
            console.print(table)
        acc = partner_id_accuracy(env, ClassifierConfig(window=self.window))
        console.print(
            f"{self.env} {split}: partner-index top-1 accuracy from the others' obs+actions "
            f"{acc['others']:.3f}, from the controlled agent's local trajectory "
            f"{acc['local']:.3f}, "
            f"chance {acc['chance']:.3f} ({acc['teams']} teams, window {self.window})"
        )
        lv_cfg = LevelsConfig()
        levels = action_levels(env, lv_cfg)
        table = Table(title=f"{self.env} {split}: partners' action-accuracy levels")
        table.add_column("level")
        table.add_column("value", justify="right")
        table.add_column("what")
        table.add_row(
            "ceiling", f"{levels['ceiling']:.3f}", escape("E[max_a pi(a|o)] under their own obs")
        )
        table.add_row(
            "memoryless",
            f"{levels['memoryless']:.3f}",
            "MLP: partner's own obs + slot -> action, pooled over teams (held out)",
        )
        table.add_row(
            "memoryless (own view)",
            f"{levels['memoryless_own']:.3f}",
            "the same from the controlled agent's current obs (an agent model without history)",
        )
        table.add_row("majority", f"{levels['majority']:.3f}", "each slot's most frequent action")
        console.print(table)
        sampled = set(levels["sampled"])
        console.print(
            "member ceilings: "
            + ", ".join(
                f"{n} {v:.3f}" + ("*" if n in sampled else "") for n, v in levels["members"].items()
            )
            + f" (* measured by sampling act {lv_cfg.samples}x per obs; others from their "
            f"probabilities); {lv_cfg.episodes_per_team} episodes per team, {levels['steps']:,} "
            "partner steps, random controlled agent"
        )
        if self.record:
            found = {
                "partner_id_accuracy_others": round(acc["others"], 3),
                "partner_id_accuracy_local": round(acc["local"], 3),
                "chance": round(acc["chance"], 4),
                "teams": acc["teams"],
                "window": self.window,
                "episodes_per_team": ClassifierConfig().episodes_per_team,
                "action_ceiling": round(levels["ceiling"], 4),
                "memoryless_accuracy": round(levels["memoryless"], 4),
                "memoryless_own_accuracy": round(levels["memoryless_own"], 4),
                "majority_rate": round(levels["majority"], 4),
                "member_ceilings": {n: round(v, 4) for n, v in levels["members"].items()},
                "ceiling_sampled": levels["sampled"],
                "levels_settings": dataclasses.asdict(lv_cfg),
                "measured_by": f"transam partners diversity {self.env}"
                + (" --heldout" if self.heldout else ""),
                "population_digest": learned.digest(self.env, split),
            }
            learned.record_diversity(self.env, split, found)
            console.print(f"recorded in {learned.data_dir(self.env) / 'manifest.json'}")


@dataclass
class PartnersImportLiam:
    """Convert LIAM's six pretrained Tag predators (.npz exports of its .pt files, with its
    LICENSE) into Tag's default population in the package data."""

    env: tyro.conf.Positional[Literal["tag"]]
    src: tyro.conf.Positional[Path]  # folder of params_{ia2c,maddpg}_agent_{0,1,2}.npz + LICENSE
    out: Path | None = None  # write here instead of the package data

    def run(self) -> None:
        from transam.partners import learned
        from transam.partners.liam import import_liam

        try:
            path = import_liam(self.src, root=self.out)
        except (FileNotFoundError, ValueError) as err:
            raise SystemExit(f"error: {err}") from None
        digest = learned.digest(self.env, "default", root=self.out)
        console.print(f"imported LIAM's predators -> {path} (digest {digest})")


@dataclass
class PartnersImportAuthors:
    """Import the TransAM authors' Spread population from YOUR checkout of their repository
    (conor-wallace/agent-transformer) into a population directory --out DIR, for
    `--partners DIR` / make_env("spread", partners=DIR). Their repository has no licence: the
    directory is for your own use, never to be redistributed (nothing of theirs ships with
    transam)."""

    env: tyro.conf.Positional[Literal["spread"]]
    path: tyro.conf.Positional[Path]
    """their repository's root (weights under pretrained_opponents/pretrained_parameters/spread/)
    or a folder holding params_{ippo,mappo}_agent_{0..3}.pt directly"""
    out: Path
    """population directory to write (manifest.json + default.safetensors), outside the
    transam package"""

    def run(self) -> None:
        from transam.partners import authors, learned

        if self.out.exists() and not self.out.is_dir():
            raise SystemExit(f"error: --out {self.out} exists and is not a directory")
        if (
            self.out.is_dir()
            and any(self.out.iterdir())
            and not (self.out / "manifest.json").exists()
        ):
            raise SystemExit(
                f"error: --out {self.out} is a non-empty folder that holds no population "
                "(manifest.json); choose an empty or new folder"
            )
        try:
            path = authors.import_spread(self.path, self.out)
        except (FileNotFoundError, ValueError) as err:
            raise SystemExit(f"error: {err}") from None
        pop = learned.directory_population("spread", self.out)
        console.print(
            f"wrote {path} and {self.out / 'default.safetensors'}: {len(authors.LEARNED)} "
            f"learned actors (argmax) + {len(authors.MEMBER_LIST[:5])} heuristics, "
            f"{len(pop.teams)} teams (digest {learned.directory_digest(self.out)})"
        )
        console.print(
            f"use: transam train --partners {self.out} (or make_env('spread', "
            f"partners='{self.out}')); licence: {authors.LICENCE}"
        )


@dataclass
class Partners:
    """Learned partner populations: train, show, diversity, import-liam, import-authors."""

    cmd: (
        Annotated[PartnersTrain, tyro.conf.subcommand("train")]
        | Annotated[PartnersImportLiam, tyro.conf.subcommand("import-liam")]
        | Annotated[PartnersShow, tyro.conf.subcommand("show")]
        | Annotated[PartnersDiversity, tyro.conf.subcommand("diversity")]
        | Annotated[PartnersImportAuthors, tyro.conf.subcommand("import-authors")]
    )

    def run(self) -> None:
        self.cmd.run()
