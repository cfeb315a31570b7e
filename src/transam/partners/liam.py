"""LIAM's pretrained Tag predators: their two network architectures and their import.

Tag's default population is LIAM's (uoe-agents/LIAM, MIT licence, (c) 2021 Autonomous Agents
Research Group, University of Edinburgh): four heuristics (:mod:`transam.partners.tag`), three
IA2C and three MADDPG predators, in LIAM's table of 10 teams as executed. The weights ship as
``data/tag/default.safetensors`` with LIAM's licence as ``data/tag/LICENSE-LIAM``; the six
``.npz`` exports of LIAM's ``.pt`` files they were made from are not shipped, so
:func:`import_liam` (``transam partners import-liam tag DIR``) documents and reproduces how.

Facts the conversion rests on (read from LIAM's ``pretrained_predators.py`` and checked against
its outputs on 512 observations, ``tests/data/liam_tag_reference.npz``):

* Input: the predator's 16-float observation as float32. Ours has the same layout, order and
  signs ([vel, pos, 2 landmarks rel, lower- then higher-indexed other predator rel, prey rel,
  prey velocity]; relative = other - self), so the builders use it unchanged.
* IA2C: relu(fc1) -> relu(fc2) -> policy logits; LIAM samples from the softmax every step.
* MADDPG: BatchNorm1d in eval mode (trained running stats, eps 1e-5) -> relu(fc1) -> relu(fc2)
  -> fc3; LIAM plays the argmax, no noise.
* Actions: the fork numbers them 0 no-op, 1 +x, 2 -x, 3 +y, 4 -y; ours are 0 no-op, 1 -x,
  2 +x, 3 -y, 4 +y. The conversion permutes the output layer's rows (:data:`TO_OURS`), so the
  shipped weights speak our numbering and nothing maps actions at play time.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from transam.partners.tag import LEARNED_SLOTS, LIAM_TABLE
from transam.partners.train import LogitsFn

REPOSITORY = "uoe-agents/LIAM"
COMMIT = "8545b9e4237eb60ad45b7cb8ed6caec6bc4263b5"
COPYRIGHT = "Copyright (c) 2021 Autonomous Agents Research Group (University of Edinburgh)"
LICENSE_FILE = "LICENSE-LIAM"
BN_EPS = 1e-5  # torch BatchNorm1d's default; not stored in LIAM's .pt files
HIDDEN = 64
OBS_DIM = 16

TO_OURS = np.array([0, 2, 1, 4, 3])
"""Our action j is LIAM's action ``TO_OURS[j]`` (no-op, -x, +x, -y, +y <- 0, 2, 1, 4, 3); the
permutation is its own inverse."""

ALGOS = ("ia2c", "maddpg")
SLOT_OF: dict[str, str] = {
    f"{algo}_{i}": slot
    for algo, prefix in zip(ALGOS, ("rl_a", "rl_b"), strict=True)
    for i, slot in enumerate(s for s in LEARNED_SLOTS if s.startswith(prefix))
}
"""LIAM member name -> the learned slot of :data:`transam.partners.tag.LIAM_TABLE` it fills."""

TEAMS: tuple[tuple[str, tuple[str, ...]], ...] = tuple(
    (f"liam{i}", tuple({v: k for k, v in SLOT_OF.items()}.get(s, s) for s in row))
    for i, row in enumerate(LIAM_TABLE)
)
"""LIAM's 10 teams as executed (task ids 0-9); entry k of a team drives predator k."""

LAYERS = {
    "ia2c": (("fc1", (HIDDEN, OBS_DIM)), ("fc2", (HIDDEN, HIDDEN)), ("policy", (5, HIDDEN))),
    "maddpg": (("fc1", (HIDDEN, OBS_DIM)), ("fc2", (HIDDEN, HIDDEN)), ("fc3", (5, HIDDEN))),
}
"""The linear layers each architecture reads (torch layout: weight [out, in]); the last one's
rows are actions."""


def _dense(p: dict[str, Any], x: jax.Array) -> jax.Array:
    """torch's Linear: ``x @ W.T + b``."""
    return x @ p["weight"].T + p["bias"]


def _check_env(env: str, entry: dict[str, Any]) -> None:
    if env != "tag":
        raise ValueError(f"member {entry['name']!r}: LIAM's predators play env 'tag', not {env!r}")


def ia2c_logits(params: dict[str, Any], entry: dict[str, Any], env: str) -> LogitsFn:
    """LIAM's IA2C actor (``IA2CPolicyNet``): relu(fc1), relu(fc2), policy logits."""
    _check_env(env, entry)
    p = jax.tree.map(jnp.asarray, params)

    def logits(obs: jax.Array) -> jax.Array:
        h = jax.nn.relu(_dense(p["fc1"], jnp.asarray(obs, jnp.float32)))
        return _dense(p["policy"], jax.nn.relu(_dense(p["fc2"], h)))

    return logits


def maddpg_logits(params: dict[str, Any], entry: dict[str, Any], env: str) -> LogitsFn:
    """LIAM's MADDPG actor (``MADDPGNet`` in eval mode): BatchNorm1d with the trained running
    statistics, then relu(fc1), relu(fc2), fc3."""
    _check_env(env, entry)
    p = jax.tree.map(jnp.asarray, params)
    bn = p["in_fn"]
    scale = bn["weight"] / jnp.sqrt(bn["running_var"] + entry["bn_eps"])

    def logits(obs: jax.Array) -> jax.Array:
        z = (jnp.asarray(obs, jnp.float32) - bn["running_mean"]) * scale + bn["bias"]
        h = jax.nn.relu(_dense(p["fc2"], jax.nn.relu(_dense(p["fc1"], z))))
        return _dense(p["fc3"], h)

    return logits


def _read_npz(path: Path, algo: str) -> dict[str, np.ndarray]:
    """One exported member, checked against the layer shapes its architecture expects."""
    if not path.is_file():
        raise FileNotFoundError(f"missing {path.name} in {path.parent} (expected LIAM's exports)")
    with np.load(path) as f:
        raw = {k: f[k] for k in f.files}
    want = {
        f"{n}.{part}": s if part == "weight" else s[:1]
        for n, s in LAYERS[algo]
        for part in ("weight", "bias")
    }
    if algo == "maddpg":
        bn = ("weight", "bias", "running_mean", "running_var")
        want |= {f"in_fn.{k}": (OBS_DIM,) for k in bn}
    for key, shape in want.items():
        if key not in raw or raw[key].shape != shape:
            got = raw[key].shape if key in raw else "missing"
            raise ValueError(f"{path.name}: {key} should have shape {shape}, got {got}")
    if algo == "maddpg" and "in_fn.eps" in raw and raw["in_fn.eps"] != np.float32(BN_EPS):
        raise ValueError(f"{path.name}: in_fn.eps is {float(raw['in_fn.eps'])}, expected {BN_EPS}")
    return {k: np.asarray(raw[k], np.float32) for k in want}


def convert(src: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """LIAM's six predators from ``src/params_{ia2c,maddpg}_agent_{0,1,2}.npz`` as the shipped
    safetensors dict and the ``default`` manifest entry (output rows in our action order)."""
    tensors: dict[str, np.ndarray] = {}
    members: list[dict[str, Any]] = []
    for algo in ALGOS:
        out_layer = LAYERS[algo][-1][0]
        for i in range(3):
            path = src / f"params_{algo}_agent_{i}.npz"
            raw = _read_npz(path, algo)
            name = f"{algo}_{i}"
            for key, arr in raw.items():
                if key.startswith(f"{out_layer}."):
                    arr = arr[TO_OURS]
                tensors[f"{name}/{key.replace('.', '/')}"] = np.ascontiguousarray(arr)
            members.append(
                {
                    "name": name,
                    "kind": algo,
                    "recipe": "liam",
                    "arch": f"liam-{algo}",
                    "act": "sample" if algo == "ia2c" else "argmax",
                    "agent": i,
                    "hidden": HIDDEN,
                    **({"bn_eps": BN_EPS} if algo == "maddpg" else {}),
                    "source_file": f"predator_prey/pretrained/params_{algo}_agent_{i}.pt",
                    "npz_sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
                }
            )
    entry = {
        "source": {
            "repository": REPOSITORY,
            "commit": COMMIT,
            "license": "MIT",
            "copyright": COPYRIGHT,
            "license_file": LICENSE_FILE,
            "converted_by": "transam partners import-liam tag DIR (transam.partners.liam)",
        },
        "action_order": (
            "output rows permuted from LIAM's fork order (0 no-op, 1 +x, 2 -x, 3 +y, 4 -y) to "
            "ours (0 no-op, 1 -x, 2 +x, 3 -y, 4 +y); the observation is used unchanged"
        ),
        "members": members,
        "teams": [{"name": n, "slots": list(s)} for n, s in TEAMS],
        "teams_note": "LIAM's table as executed (pretrained_predators.py); slot k drives "
        "predator k; the heuristics are transam.partners.tag's",
    }
    return tensors, entry


def import_liam(src: Path, root: Path | None = None) -> Path:
    """Convert LIAM's exports in ``src`` into Tag's ``default`` split (in ``root``, default the
    package data), with LIAM's licence copied verbatim next to it. Returns the manifest path."""
    from transam.partners import learned  # learned registers this module's architectures

    licence = src / "LICENSE"
    if not licence.is_file():
        raise FileNotFoundError(f"missing LICENSE in {src}: LIAM's MIT licence must ship too")
    tensors, entry = convert(src)
    path = learned.save("tag", "default", tensors, entry, root)
    shutil.copyfile(licence, path.parent / LICENSE_FILE)
    return path
