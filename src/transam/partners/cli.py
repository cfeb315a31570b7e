"""``transam partners ...`` subcommands (tyro dataclasses with a ``run`` method).

Wire into ``transam.cli`` as ``Annotated[Partners, tyro.conf.subcommand("partners")]``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro
from rich.console import Console
from rich.table import Table

EnvName = Literal["tag", "spread", "overcooked", "lbf"]
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
        r = recipe(self.env, self.heldout)
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
        cols = ("member", "kind", "recipe", "seed", "shaping", "gamma", "steps", "self-play")
        extra = ("touches",) if touches else ()
        for c in (*cols, "measured", *extra):
            table.add_column(c, justify="left" if c in ("member", "recipe") else "right")
        for m in entry["members"]:
            table.add_row(
                m["name"],
                m["kind"],
                m["recipe"],
                str(m["seed"]),
                m["shaping"],
                f"{m['gamma']:g}",
                f"{m['steps']:,}",
                f"{m['self_play_return']:.3f}",
                f"{measured[m['name']]:.3f}",
                *([f"{touches[m['name']]:.2f}"] if extra else []),
            )
        console.print(table)
        console.print(f"random play: {entry['random_return']}")
        if extra:
            rnd = {k.split("/")[1]: round(v, 2) for k, v in touches.items() if "/" in k}
            console.print(
                f"touches: steps per episode with a predator within the capture distance of "
                f"the prey; random predators: {rnd}"
            )
        if entry["teams"]:
            console.print("teams: " + ", ".join(t["name"] for t in entry["teams"]))
        console.print(
            "self-play: the member's training run (manifest); measured: every learner slot "
            f"played by this member, against the run's stand-in ({self.episodes} episodes)"
        )


@dataclass
class PartnersDiversity:
    """Cross-play matrix (LBF, Overcooked) and partner-index classifier accuracy vs chance."""

    env: tyro.conf.Positional[EnvName]
    heldout: bool = False
    window: int = 10  # steps per classifier sample
    record: bool = False  # store the accuracies in the shipped manifest (the README quotes it)

    def run(self) -> None:
        from transam.compose import make_env
        from transam.partners import learned
        from transam.partners.diversity import ClassifierConfig, cross_play, partner_id_accuracy

        split = _split(self.heldout)
        env = make_env(self.env, population=learned.population(self.env, split))
        if not 1 <= self.window <= env.spec.episode_len:
            raise SystemExit(
                f"error: --window must be between 1 and {self.env}'s episode length "
                f"{env.spec.episode_len} (a window stays inside one episode), got {self.window}"
            )
        if self.env in ("lbf", "overcooked"):
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
        if self.record:
            found = {
                "partner_id_accuracy_others": round(acc["others"], 3),
                "partner_id_accuracy_local": round(acc["local"], 3),
                "chance": round(acc["chance"], 4),
                "teams": acc["teams"],
                "window": self.window,
                "episodes_per_team": ClassifierConfig().episodes_per_team,
                "measured_by": f"transam partners diversity {self.env}"
                + (" --heldout" if self.heldout else ""),
                "population_digest": learned.digest(self.env, split),
            }
            learned.record_diversity(self.env, split, found)
            console.print(f"recorded in {learned.data_dir(self.env) / 'manifest.json'}")


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
    """Learned partner populations: train, show, diversity, import-authors."""

    cmd: (
        Annotated[PartnersTrain, tyro.conf.subcommand("train")]
        | Annotated[PartnersShow, tyro.conf.subcommand("show")]
        | Annotated[PartnersDiversity, tyro.conf.subcommand("diversity")]
        | Annotated[PartnersImportAuthors, tyro.conf.subcommand("import-authors")]
    )

    def run(self) -> None:
        self.cmd.run()
