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
    steps: int | None = None  # override every family's training budget (smoke runs)
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
        console.print(
            f"trained {len(entry['members'])} members in {time.time() - t0:.1f}s -> {path}"
        )


@dataclass
class PartnersShow:
    """Print ENV's manifest with each member's measured return against its stand-in."""

    env: tyro.conf.Positional[EnvName]
    heldout: bool = False

    def run(self) -> None:
        from transam.partners import learned

        split = _split(self.heldout)
        entry = learned.load_manifest(self.env)[split]
        members = learned.learned_members(self.env, split)
        measured = _measure(self.env, entry["members"], members)
        table = Table(title=f"{self.env} {split} learned partners")
        cols = ("member", "kind", "recipe", "seed", "shaping", "gamma", "steps", "self-play")
        for c in (*cols, "measured"):
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
            )
        console.print(table)
        console.print(f"random play: {entry['random_return']}")
        if entry["teams"]:
            console.print("teams: " + ", ".join(t["name"] for t in entry["teams"]))
        console.print(
            "self-play: the member's training run (manifest); measured: every learner slot "
            "played by this member, against the run's stand-in (16 episodes)"
        )


def _measure(env: str, rows: list[dict], members: dict) -> dict[str, float]:
    """Mean score with every learner slot played by one member (one program per stand-in)."""
    import jax
    import jax.numpy as jnp

    from transam.partners import learned
    from transam.partners.joint import play

    out: dict[str, float] = {}
    for stand_in in sorted({m["stand_in"] for m in rows}):
        names = [m["name"] for m in rows if m["stand_in"] == stand_in]
        acts = [members[n].act for n in names]
        view = learned.joint_view(env, stand_in)

        def score(idx: jax.Array, acts: list = acts, view: learned.JointView = view) -> jax.Array:
            pol = lambda k, o: jax.lax.switch(idx, acts, k, o)
            return jnp.mean(play(view, [pol] * view.num_agents, jax.random.PRNGKey(1), 16)[0])

        vals = jax.jit(jax.vmap(score))(jnp.arange(len(names)))
        out.update({n: float(v) for n, v in zip(names, vals, strict=True)})
    return out


@dataclass
class PartnersDiversity:
    """Cross-play matrix (LBF, Overcooked) and partner-index classifier accuracy vs chance."""

    env: tyro.conf.Positional[EnvName]
    heldout: bool = False
    window: int = 10  # steps per classifier sample

    def run(self) -> None:
        from transam import envs
        from transam.partners import learned
        from transam.partners.diversity import ClassifierConfig, cross_play, partner_id_accuracy

        split = _split(self.heldout)
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
        pop = learned.population(self.env, split)
        acc = partner_id_accuracy(
            envs.make(self.env, population=pop), ClassifierConfig(window=self.window)
        )
        console.print(
            f"{self.env} {split}: partner-index top-1 accuracy from the others' obs+actions "
            f"{acc['others']:.3f}, from the controlled agent's local trajectory "
            f"{acc['local']:.3f}, "
            f"chance {acc['chance']:.3f} ({acc['teams']} teams, window {self.window})"
        )


@dataclass
class Partners:
    """Learned partner populations: train, show, diversity."""

    cmd: (
        Annotated[PartnersTrain, tyro.conf.subcommand("train")]
        | Annotated[PartnersShow, tyro.conf.subcommand("show")]
        | Annotated[PartnersDiversity, tyro.conf.subcommand("diversity")]
    )

    def run(self) -> None:
        self.cmd.run()
