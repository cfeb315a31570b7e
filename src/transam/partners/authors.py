"""The TransAM authors' Spread population, imported from a user's own checkout of their code.

``transam partners import-authors spread PATH --out DIR`` reads the authors' actor weights
(``conor-wallace/agent-transformer``, ``pretrained_opponents/pretrained_parameters/spread/
params_{ippo,mappo}_agent_{0..3}.pt``) and writes a population directory in the shipped format
(``manifest.json`` + ``default.safetensors``; see :mod:`transam.compose`) that
``make_env("spread", partners=DIR)`` and ``--partners DIR`` play.

**Licence.** The authors' repository has no licence: all rights are reserved by its authors.
Nothing of theirs is shipped with transam; the importer runs on the user's own copy and writes
outside the package, and the manifest records the source files' sha256 and "no licence: do not
redistribute".

**Reading the .pt files without torch.** They are torch's legacy (pre-1.6, non-zip) format:
consecutive pickles (protocol 2) of the magic number ``0x1950a86a20f9469cfc6c``, the protocol
version 1001, ``sys_info``, the state dict (an ``OrderedDict`` of tensors, each pickled as a
call to ``torch._utils._rebuild_tensor_v2`` on a persistent storage id ``('storage',
torch.FloatStorage, key, location, numel, view_metadata)``) and the list of storage keys, then
for each key an int64 little-endian element count and the raw little-endian float32 values.
:func:`read_legacy_pt` reads exactly that with a restricted :class:`pickle.Unpickler` (only
the three globals the format uses; anything else is refused) plus numpy.

**The wiring, as their loader executes it** (``PPONet(18, 5, 64)`` in
``pretrained_spread_opponents.py``, the same for ippo and mappo; :func:`authors_logits`)::

    x = LayerNorm(18)(obs)                                   base.feature_norm
    x = LayerNorm(64)(tanh(Linear(18 -> 64)(x)))             base.mlp.fc1.{0,2}
    x = LayerNorm(64)(tanh(Linear(64 -> 64)(x)))             base.mlp.fc2.0.{0,2}
    logits = Linear(64 -> 5)(x)                              act.action_out.linear

LayerNorms with the biased variance and eps 1e-5; the action is the **argmax** (``"act":
"argmax"``). ``base.mlp.fc_h.*`` is never run by their forward, and the ippo files' GRU
(``rnn.*``) is dropped by their loader: both are ignored here too.

**Action numbering, converted in one place: at import.** The fork numbers the moves 0 no-op,
1 +x, 2 -x, 3 +y, 4 -y; ours (mpe2/JaxMARL) 0 no-op, 1 -x, 2 +x, 3 -y, 4 +y. The importer
permutes the rows of the action head (:data:`FORK_TO_OURS`, its own inverse), so the stored
weights and every logit they produce speak our numbering; nothing maps at act time.

**Members and teams, as executed**: the eight learned actors ``ippo_0..3``, ``mappo_0..3``
(their ``mappo_4``/``_5`` are byte copies of 2/3 that no team uses) and the authors' five
heuristics by their names (:data:`transam.partners.spread.AUTHORS_HEURISTICS`, resolved from
the Spread heuristic pool at load); the 13 teams of :data:`AUTHORS_TEAMS`, slot 0 driving
agent 0 and slot 1 agent 1 (the controlled agent is agent 2), drawn uniformly per episode.
"""

from __future__ import annotations

import hashlib
import io
import json
import pickle
from collections import OrderedDict
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from safetensors.numpy import save_file

from transam.partners.train import LogitsFn

ARCH = "authors-ppo"
REPOSITORY = "https://github.com/conor-wallace/agent-transformer"
SPREAD_SUBDIR = Path("pretrained_opponents") / "pretrained_parameters" / "spread"
LICENCE = (
    "none: the authors' repository has no licence (all rights reserved by its authors); "
    "for your own use only, do not redistribute these weights or this directory"
)
LEGACY_MAGIC = 0x1950A86A20F9469CFC6C
LEGACY_PROTOCOL = 1001
LN_EPS = 1e-5
OBS_DIM, HIDDEN, NUM_ACTIONS = 18, 64, 5

FORK_TO_OURS = np.asarray([0, 2, 1, 4, 3])
"""Our action index of each fork action (and, being its own inverse, the fork index of each of
ours): fork 1 +x = our 2, fork 2 -x = our 1, fork 3 +y = our 4, fork 4 -y = our 3."""

LEARNED = tuple(f"{kind}_{i}" for kind in ("ippo", "mappo") for i in range(4))
"""The learned members the teams use, as ``<kind>_<i>`` (file ``params_<kind>_agent_<i>.pt``)."""

MEMBER_LIST = (
    "after_first_landmark",
    "after_second_landmark",
    "after_third_landmark",
    "after_farthest_landmark",
    "after_closest_landmark",
    *LEARNED,
    "mappo_4",
    "mappo_5",
)
"""The authors' 15-entry member list ``opp``, in their order (their team table indexes it)."""

RAW_TEAMS = (
    (0, 6),
    (1, 10),
    (2, 8),
    (3, 12),
    (4, 6),
    (5, 0),
    (9, 1),
    (7, 2),
    (11, 3),
    (5, 10),
    (7, 12),
    (9, 6),
    (11, 8),
)
"""Their team table ``index`` as the code indexes :data:`MEMBER_LIST` (the comments beside it
in their file use another numbering and are wrong): column 0 drives agent 0, column 1 agent 1."""

AUTHORS_TEAMS: tuple[tuple[str, str], ...] = tuple(
    (MEMBER_LIST[a], MEMBER_LIST[b]) for a, b in RAW_TEAMS
)
"""The 13 teams as executed, by member name (9 heuristic + learned, 4 learned + learned)."""

# State-dict key -> (our parameter path, transpose) for the layers their forward runs.
_KEYS = {
    "base.feature_norm.weight": ("feature_norm/scale", False),
    "base.feature_norm.bias": ("feature_norm/bias", False),
    "base.mlp.fc1.0.weight": ("fc1/kernel", True),
    "base.mlp.fc1.0.bias": ("fc1/bias", False),
    "base.mlp.fc1.2.weight": ("fc1_norm/scale", False),
    "base.mlp.fc1.2.bias": ("fc1_norm/bias", False),
    "base.mlp.fc2.0.0.weight": ("fc2/kernel", True),
    "base.mlp.fc2.0.0.bias": ("fc2/bias", False),
    "base.mlp.fc2.0.2.weight": ("fc2_norm/scale", False),
    "base.mlp.fc2.0.2.bias": ("fc2_norm/bias", False),
    "act.action_out.linear.weight": ("head/kernel", True),
    "act.action_out.linear.bias": ("head/bias", False),
}
_SHAPES = {
    "base.feature_norm.weight": (OBS_DIM,),
    "base.feature_norm.bias": (OBS_DIM,),
    "base.mlp.fc1.0.weight": (HIDDEN, OBS_DIM),
    "base.mlp.fc1.0.bias": (HIDDEN,),
    "base.mlp.fc1.2.weight": (HIDDEN,),
    "base.mlp.fc1.2.bias": (HIDDEN,),
    "base.mlp.fc2.0.0.weight": (HIDDEN, HIDDEN),
    "base.mlp.fc2.0.0.bias": (HIDDEN,),
    "base.mlp.fc2.0.2.weight": (HIDDEN,),
    "base.mlp.fc2.0.2.bias": (HIDDEN,),
    "act.action_out.linear.weight": (NUM_ACTIONS, HIDDEN),
    "act.action_out.linear.bias": (NUM_ACTIONS,),
}


class LegacyPtError(ValueError):
    """A .pt file this reader cannot read (the message names the file and the reason)."""


# ---------------------------------------------------------------- the torch-free reader


class _FloatStorage:
    """Stands for ``torch.FloatStorage`` (the only storage type the format may name)."""


class _Storage:
    def __init__(self, key: str, numel: int) -> None:
        self.key, self.numel = key, numel


class _TensorRef:
    """A tensor as the pickle describes it; its values come from the trailing storages."""

    def __init__(
        self, storage: _Storage, offset: int, size: tuple[int, ...], stride: tuple[int, ...]
    ) -> None:
        self.storage, self.offset, self.size, self.stride = storage, offset, size, stride


def _rebuild_tensor_v2(
    storage: Any,
    storage_offset: Any,
    size: Any,
    stride: Any,
    requires_grad: Any = False,
    backward_hooks: Any = None,
    metadata: Any = None,
) -> _TensorRef:
    del requires_grad, backward_hooks, metadata
    if not isinstance(storage, _Storage):
        raise pickle.UnpicklingError(f"tensor storage is {type(storage).__name__}, not a storage")
    return _TensorRef(storage, int(storage_offset), tuple(size), tuple(stride))


_GLOBALS: dict[tuple[str, str], Any] = {
    ("torch._utils", "_rebuild_tensor_v2"): _rebuild_tensor_v2,
    ("torch", "FloatStorage"): _FloatStorage,
    ("collections", "OrderedDict"): OrderedDict,
}


class _Unpickler(pickle.Unpickler):
    """Resolves only the globals of a float32 legacy state dict; storages by persistent id."""

    def __init__(self, f: io.BytesIO) -> None:
        super().__init__(f)
        self.storages: dict[str, _Storage] = {}

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in _GLOBALS:
            allowed = ", ".join(f"{m}.{n}" for m, n in _GLOBALS)
            raise pickle.UnpicklingError(f"unexpected global {module}.{name} (allowed: {allowed})")
        return _GLOBALS[(module, name)]

    def persistent_load(self, pid: Any) -> _Storage:
        if not (isinstance(pid, tuple) and len(pid) >= 5 and pid[0] == "storage"):
            raise pickle.UnpicklingError(f"unexpected persistent id {pid!r}")
        _, storage_type, key, _location, numel = pid[:5]
        if storage_type is not _FloatStorage:
            raise pickle.UnpicklingError(f"storage type {storage_type!r} is not FloatStorage")
        if len(pid) > 5 and pid[5] is not None:
            raise pickle.UnpicklingError(f"storage {key!r} is a view ({pid[5]!r}); not supported")
        key = str(key)
        if key not in self.storages:
            self.storages[key] = _Storage(key, int(numel))
        return self.storages[key]


def _load_one(f: io.BytesIO) -> Any:
    return _Unpickler(f).load()


def read_legacy_pt(path: str | Path) -> OrderedDict[str, np.ndarray]:
    """The state dict in a legacy-format (pre-1.6, non-zip) torch ``.pt`` file, as float32
    numpy arrays, without torch (the module docstring describes the format).

    Raises :class:`LegacyPtError` naming the file for anything else: a missing file, a
    zip-format (torch >= 1.6) file, a wrong magic number or protocol, a truncated file, a
    global or storage type outside the format.
    """
    path = Path(path)
    if not path.is_file():
        raise LegacyPtError(f"{path}: no such file")
    data = path.read_bytes()
    if data[:4] == b"PK\x03\x04":
        raise LegacyPtError(
            f"{path}: a zip-format torch file (torch >= 1.6); this reader reads only the legacy "
            "format of the authors' files (pickle protocol 2 then raw storages)"
        )
    if data[:2] != b"\x80\x02":
        raise LegacyPtError(f"{path}: not a legacy torch file (no pickle protocol 2 header)")
    f = io.BytesIO(data)
    try:
        magic = _load_one(f)
        if magic != LEGACY_MAGIC:
            raise LegacyPtError(f"{path}: magic number {magic!r}, expected {LEGACY_MAGIC:#x}")
        protocol = _load_one(f)
        if protocol != LEGACY_PROTOCOL:
            raise LegacyPtError(f"{path}: protocol {protocol!r}, expected {LEGACY_PROTOCOL}")
        sys_info = _load_one(f)
        if isinstance(sys_info, dict) and sys_info.get("little_endian") is False:
            raise LegacyPtError(f"{path}: written big-endian; not supported")
        unpickler = _Unpickler(f)
        obj = unpickler.load()
        keys = _load_one(f)
    except LegacyPtError:
        raise
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError) as err:
        raise LegacyPtError(f"{path}: not a readable legacy torch file ({err})") from None
    if not isinstance(obj, dict) or not all(isinstance(v, _TensorRef) for v in obj.values()):
        raise LegacyPtError(f"{path}: the saved object is not a state dict of tensors")
    if not isinstance(keys, list) or set(map(str, keys)) != set(unpickler.storages):
        raise LegacyPtError(f"{path}: the storage key list does not match the tensors' storages")
    values: dict[str, np.ndarray] = {}
    pos = f.tell()
    for key in map(str, keys):
        if pos + 8 > len(data):
            raise LegacyPtError(f"{path}: truncated (storage {key!r} is missing)")
        count = int(np.frombuffer(data, "<i8", 1, pos)[0])
        pos += 8
        if count != unpickler.storages[key].numel or pos + 4 * count > len(data):
            raise LegacyPtError(
                f"{path}: truncated or inconsistent storage {key!r} ({count} elements, "
                f"{unpickler.storages[key].numel} expected, {len(data) - pos} bytes left)"
            )
        values[key] = np.frombuffer(data, "<f4", count, pos)
        pos += 4 * count
    if pos != len(data):
        raise LegacyPtError(f"{path}: {len(data) - pos} unexpected bytes after the storages")
    out: OrderedDict[str, np.ndarray] = OrderedDict()
    for name, ref in obj.items():
        flat = values[ref.storage.key]
        need = ref.offset + sum((n - 1) * s for n, s in zip(ref.size, ref.stride, strict=True))
        if len(ref.size) != len(ref.stride) or (all(ref.size) and need >= len(flat)):
            raise LegacyPtError(f"{path}: tensor {name!r} lies outside its storage")
        arr = np.lib.stride_tricks.as_strided(
            flat[ref.offset :], ref.size, tuple(4 * s for s in ref.stride)
        )
        out[str(name)] = np.array(arr, dtype=np.float32)  # a copy: native order, writable
    return out


# ---------------------------------------------------------------- the wiring


def _layer_norm(x: jax.Array, p: dict[str, Any]) -> jax.Array:
    mean = jnp.mean(x, -1, keepdims=True)
    var = jnp.mean(jnp.square(x - mean), -1, keepdims=True)  # biased, as torch
    return (x - mean) / jnp.sqrt(var + LN_EPS) * p["scale"] + p["bias"]


def _dense(x: jax.Array, p: dict[str, Any]) -> jax.Array:
    return jnp.dot(x, p["kernel"], precision=jax.lax.Precision.HIGHEST) + p["bias"]


def authors_logits(params: dict[str, Any], entry: dict[str, Any], env: str) -> LogitsFn:
    """The ``"authors-ppo"`` architecture: their actor as their loader runs it (module doc),
    logits in our action numbering (the importer permuted the head)."""
    del entry
    if env != "spread":
        raise ValueError(f"arch {ARCH!r} is the authors' Spread actor; env {env!r} given")
    p = jax.tree.map(lambda a: jnp.asarray(a, jnp.float32), params)

    def logits(obs: jax.Array) -> jax.Array:
        x = _layer_norm(jnp.asarray(obs, jnp.float32), p["feature_norm"])
        x = _layer_norm(jnp.tanh(_dense(x, p["fc1"])), p["fc1_norm"])
        x = _layer_norm(jnp.tanh(_dense(x, p["fc2"])), p["fc2_norm"])
        return _dense(x, p["head"])

    return logits


def convert(state: dict[str, np.ndarray], source: str = "state dict") -> dict[str, np.ndarray]:
    """Our flat ``<param path> -> array`` of one of their actors: the layers their forward runs
    (``fc_h`` and ``rnn.*`` dropped), kernels as (in, out), head rows in our action order."""
    out: dict[str, np.ndarray] = {}
    for key, (ours, transpose) in _KEYS.items():
        if key not in state:
            raise LegacyPtError(f"{source}: key {key!r} missing (keys: {', '.join(state)})")
        arr = np.asarray(state[key], np.float32)
        if arr.shape != _SHAPES[key]:
            raise LegacyPtError(f"{source}: {key} has shape {arr.shape}, expected {_SHAPES[key]}")
        if key.startswith("act."):
            arr = arr[FORK_TO_OURS]  # output rows: fork numbering -> ours
        out[ours] = np.ascontiguousarray(arr.T if transpose else arr)
    return out


# ---------------------------------------------------------------- the importer


def _file_name(member: str) -> str:
    kind, i = member.rsplit("_", 1)
    return f"params_{kind}_agent_{i}.pt"


def find_files(path: str | Path) -> dict[str, Path]:
    """Member -> .pt file under ``path``: a checkout of their repository (files under
    ``pretrained_opponents/pretrained_parameters/spread/``) or a folder holding the files."""
    path = Path(path)
    names = [_file_name(m) for m in LEARNED]
    for folder in (path / SPREAD_SUBDIR, path):
        if all((folder / n).is_file() for n in names):
            return {m: folder / n for m, n in zip(LEARNED, names, strict=True)}
    where = path / SPREAD_SUBDIR
    missing = [n for n in names if not (where / n).is_file() and not (path / n).is_file()]
    raise FileNotFoundError(
        f"the authors' Spread weights are not under {path}: expected "
        f"{where}/params_{{ippo,mappo}}_agent_{{0,1,2,3}}.pt (a checkout of {REPOSITORY}) or "
        f"those files directly in {path}; missing: {', '.join(missing) or 'some of them'}"
    )


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def import_spread(path: str | Path, out: str | Path) -> Path:
    """Write the authors' Spread population read from ``path`` (see :func:`find_files`) into
    the population directory ``out`` (``manifest.json`` + ``default.safetensors``); returns
    the manifest's path. ``out`` must lie outside the transam package."""
    out = Path(out)
    _check_outside_package(out)
    files = find_files(path)
    tensors: dict[str, np.ndarray] = {}
    members = []
    for name, file in files.items():
        for p, arr in convert(read_legacy_pt(file), str(file)).items():
            tensors[f"{name}/{p}"] = arr
        members.append(
            {
                "name": name,
                "kind": name.split("_")[0],
                "recipe": "authors",
                "arch": ARCH,
                "act": "argmax",
                "hidden": HIDDEN,
                "source_file": file.name,
                "sha256": _sha256(file),
            }
        )
    entry = {
        "members": members,
        "heuristics": list(MEMBER_LIST[:5]),
        "teams": [{"name": f"{a}+{b}", "slots": [a, b]} for a, b in AUTHORS_TEAMS],
    }
    manifest = {
        "env": "spread",
        "config": {"dynamics": "authors"},
        "name": "spread-authors",
        "default": entry,
        "provenance": {
            "repository": REPOSITORY,
            "path": SPREAD_SUBDIR.as_posix(),
            "files": {f.name: _sha256(f) for f in files.values()},
            "licence": LICENCE,
            "imported_by": "transam partners import-authors spread",
            "wiring": (
                "LayerNorm(18) -> Linear(18,64) tanh LayerNorm -> Linear(64,64) tanh LayerNorm "
                "-> Linear(64,5), argmax (their loader's forward: fc_h and the ippo GRU unused); "
                "head rows permuted from the fork's action order (1 +x, 2 -x, 3 +y, 4 -y) to "
                "ours (1 -x, 2 +x, 3 -y, 4 +y)"
            ),
            "teams": "their 13-row table as their code indexes its 15-entry member list "
            "(slot 0 = agent 0, slot 1 = agent 1; mappo_4/5 unused)",
        },
    }
    out.mkdir(parents=True, exist_ok=True)
    weights = out / "default.safetensors"
    save_file(tensors, str(weights.with_suffix(".tmp")))
    weights.with_suffix(".tmp").replace(weights)
    path_out = out / "manifest.json"
    tmp = path_out.with_suffix(".tmp")
    tmp.write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    tmp.replace(path_out)
    return path_out


def _check_outside_package(out: Path) -> None:
    import transam

    package = Path(transam.__file__).resolve().parent
    target = out.resolve()
    if target == package or package in target.parents:
        raise ValueError(
            f"--out {out} lies inside the transam package ({package}); the authors' weights "
            "have no licence and must not be placed where they could be shipped: choose a "
            "folder outside it"
        )
