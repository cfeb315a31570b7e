"""The authors' Spread population importer, its torch-free .pt reader, and population
directories (``make_env(..., partners=DIR)``, ``--partners DIR``).

Tests that use the authors' own files need ``/work/shared/reference/authors-spread`` (their
repository has no licence: nothing of it is shipped, so those tests skip without the folder);
the others write legacy-format .pt files themselves with :class:`_LegacyPickler`.
"""

from __future__ import annotations

import dataclasses
import io
import json
import pickle
import zipfile
from collections import OrderedDict
from pathlib import Path
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from transam import make_env
from transam.cli import main
from transam.envs import EnvError
from transam.envs.rollout import episode_stats, make_random_rollout
from transam.envs.spread import Config as SpreadConfig
from transam.partners import authors, learned
from transam.partners.moves import DOWN, LEFT, RIGHT, UP
from transam.partners.spread import landmark_agent
from transam.rundir import RunDirError
from transam.train.config import A2CConfig, ConfigError, EvalConfig, TrainConfig
from transam.train.loop import train

REFERENCE = Path(__file__).resolve().parents[2] / "shared" / "reference" / "authors-spread"
FORK_TO_OURS = np.asarray([0, RIGHT, LEFT, UP, DOWN])  # fork 1 +x, 2 -x, 3 +y, 4 -y

# The README's team table as executed (agent 0, agent 1).
README_TEAMS = [
    ("after_first_landmark", "ippo_1"),
    ("after_second_landmark", "mappo_1"),
    ("after_third_landmark", "ippo_3"),
    ("after_farthest_landmark", "mappo_3"),
    ("after_closest_landmark", "ippo_1"),
    ("ippo_0", "after_first_landmark"),
    ("mappo_0", "after_second_landmark"),
    ("ippo_2", "after_third_landmark"),
    ("mappo_2", "after_farthest_landmark"),
    ("ippo_0", "mappo_1"),
    ("ippo_2", "mappo_3"),
    ("mappo_0", "ippo_1"),
    ("mappo_2", "ippo_3"),
]


def _need_reference() -> Path:
    if not (REFERENCE / "reference_io.npz").exists():
        pytest.skip(f"reference folder {REFERENCE} absent (the authors' Spread fixtures)")
    return REFERENCE


# ------------------------------------------------------------ a legacy .pt writer (test only)


class _TorchGlobal:
    """Stands for a torch global; pickled by name (GLOBAL ``module\\nname``)."""

    def __init__(self, module: str, name: str) -> None:
        self.module, self.name = module, name

    def __call__(self, *args: Any) -> None:  # pickle requires a reduce function be callable
        raise NotImplementedError


REBUILD = _TorchGlobal("torch._utils", "_rebuild_tensor_v2")
FLOAT_STORAGE = _TorchGlobal("torch", "FloatStorage")


class _Storage:
    def __init__(self, key: str, values: np.ndarray) -> None:
        self.key, self.values = key, np.asarray(values, "<f4").ravel()


class _Tensor:
    """A tensor viewing ``storage`` (offset and strides in elements), pickled as torch does."""

    def __init__(
        self, storage: _Storage, offset: int, size: tuple[int, ...], stride: tuple[int, ...]
    ) -> None:
        self.storage, self.offset, self.size, self.stride = storage, offset, size, stride


class _LegacyPickler(pickle._Pickler):  # type: ignore[name-defined,misc]
    """Emits the opcodes of torch's legacy save: tensors as ``_rebuild_tensor_v2`` calls on
    persistent storage ids ``('storage', torch.FloatStorage, key, 'cpu', numel, None)``."""

    dispatch: ClassVar[dict[type, Any]] = dict(pickle._Pickler.dispatch)  # type: ignore[attr-defined]

    def persistent_id(self, obj: Any) -> Any:
        if isinstance(obj, _Storage):
            return ("storage", FLOAT_STORAGE, obj.key, "cpu", obj.values.size, None)
        return None

    def reducer_override(self, obj: Any) -> Any:
        if isinstance(obj, _Tensor):
            args = (obj.storage, obj.offset, obj.size, obj.stride, False, OrderedDict())
            return (REBUILD, args)
        return NotImplemented

    def save_torch_global(self, obj: _TorchGlobal) -> None:
        self.write(pickle.GLOBAL + f"{obj.module}\n{obj.name}\n".encode())
        self.memoize(obj)


_LegacyPickler.dispatch[_TorchGlobal] = _LegacyPickler.save_torch_global


def _dump(obj: Any) -> bytes:
    buf = io.BytesIO()
    _LegacyPickler(buf, protocol=2).dump(obj)
    return buf.getvalue()


def write_legacy_pt(path: Path, tensors: dict[str, _Tensor]) -> None:
    """A file as torch.serialization._legacy_save writes it."""
    storages = list({id(t.storage): t.storage for t in tensors.values()}.values())
    sys_info = {
        "protocol_version": 1001,
        "little_endian": True,
        "type_sizes": {"short": 2, "int": 4, "long": 4},
    }
    parts = [_dump(authors.LEGACY_MAGIC), _dump(1001), _dump(sys_info)]
    parts += [_dump(OrderedDict(tensors)), _dump([s.key for s in storages])]
    for s in storages:
        parts += [np.int64(s.values.size).astype("<i8").tobytes(), s.values.tobytes()]
    path.write_bytes(b"".join(parts))


def _contiguous(key: str, arr: np.ndarray) -> _Tensor:
    arr = np.asarray(arr, np.float32)
    stride = tuple(int(s) // 4 for s in np.ascontiguousarray(arr).strides)
    return _Tensor(_Storage(key, arr), 0, arr.shape, stride)


def write_fake_actor(path: Path, rng: np.random.Generator, recurrent: bool) -> dict[str, Any]:
    """An actor file with their keys and shapes (random values; ``recurrent``: the ippo GRU
    keys too); returns the state dict as numpy arrays."""
    keys = [
        ("base.feature_norm.weight", (18,)),
        ("base.feature_norm.bias", (18,)),
        ("base.mlp.fc1.0.weight", (64, 18)),
        ("base.mlp.fc1.0.bias", (64,)),
        ("base.mlp.fc1.2.weight", (64,)),
        ("base.mlp.fc1.2.bias", (64,)),
        ("base.mlp.fc_h.0.weight", (64, 64)),
        ("base.mlp.fc_h.0.bias", (64,)),
        ("base.mlp.fc_h.2.weight", (64,)),
        ("base.mlp.fc_h.2.bias", (64,)),
        ("base.mlp.fc2.0.0.weight", (64, 64)),
        ("base.mlp.fc2.0.0.bias", (64,)),
        ("base.mlp.fc2.0.2.weight", (64,)),
        ("base.mlp.fc2.0.2.bias", (64,)),
    ]
    if recurrent:
        keys += [
            ("rnn.rnn.weight_ih_l0", (192, 64)),
            ("rnn.rnn.weight_hh_l0", (192, 64)),
            ("rnn.rnn.bias_ih_l0", (192,)),
            ("rnn.rnn.bias_hh_l0", (192,)),
            ("rnn.norm.weight", (64,)),
            ("rnn.norm.bias", (64,)),
        ]
    keys += [("act.action_out.linear.weight", (5, 64)), ("act.action_out.linear.bias", (5,))]
    state = {k: rng.normal(size=s).astype(np.float32) * 0.5 for k, s in keys}
    write_legacy_pt(path, {k: _contiguous(str(i), v) for i, (k, v) in enumerate(state.items())})
    return state


def _numpy_logits(state: dict[str, np.ndarray], obs: np.ndarray) -> np.ndarray:
    """Their forward in float64 numpy, fork action order."""

    def ln(x: np.ndarray, key: str) -> np.ndarray:
        m, v = x.mean(-1, keepdims=True), x.var(-1, keepdims=True)
        return (x - m) / np.sqrt(v + 1e-5) * state[f"{key}.weight"] + state[f"{key}.bias"]

    def lin(x: np.ndarray, key: str) -> np.ndarray:
        return x @ state[f"{key}.weight"].T.astype(np.float64) + state[f"{key}.bias"]

    x = ln(obs.astype(np.float64), "base.feature_norm")
    x = ln(np.tanh(lin(x, "base.mlp.fc1.0")), "base.mlp.fc1.2")
    x = ln(np.tanh(lin(x, "base.mlp.fc2.0.0")), "base.mlp.fc2.0.2")
    return lin(x, "act.action_out.linear")


@pytest.fixture(scope="module")
def fake_checkout(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A folder laid out as their repository, with random-valued actor files."""
    root = tmp_path_factory.mktemp("checkout")
    folder = root / authors.SPREAD_SUBDIR
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    states = {
        m: write_fake_actor(
            folder / f"params_{m.split('_')[0]}_agent_{m[-1]}.pt", rng, m.startswith("ippo")
        )
        for m in authors.LEARNED
    }
    return root, states


@pytest.fixture(scope="module")
def fake_population(
    fake_checkout: tuple[Path, dict[str, Any]], tmp_path_factory: pytest.TempPathFactory
) -> Path:
    out = tmp_path_factory.mktemp("pop") / "authors-fake"
    authors.import_spread(fake_checkout[0], out)
    return out


# ------------------------------------------------------------ the reader


def test_reader_reads_a_legacy_file_exactly(tmp_path: Path) -> None:
    """Contiguous tensors, a shared storage with an offset, and a transposed (strided) view."""
    rng = np.random.default_rng(1)
    a = rng.normal(size=(3, 4)).astype(np.float32)
    shared = _Storage("shared", np.arange(10, dtype=np.float32))
    tensors = {
        "a": _contiguous("0", a),
        "tail": _Tensor(shared, 4, (2, 3), (3, 1)),
        "t": _Tensor(shared, 0, (2, 2), (1, 2)),
        "scalar_vec": _contiguous("2", np.asarray([7.5], np.float32)),
    }
    path = tmp_path / "x.pt"
    write_legacy_pt(path, tensors)
    assert path.read_bytes()[:4] == b"\x80\x02\x8a\x0a"  # protocol 2, LONG1 of the magic
    got = authors.read_legacy_pt(path)
    assert list(got) == ["a", "tail", "t", "scalar_vec"]
    np.testing.assert_array_equal(got["a"], a)
    np.testing.assert_array_equal(got["tail"], np.arange(4, 10, dtype=np.float32).reshape(2, 3))
    np.testing.assert_array_equal(got["t"], np.asarray([[0, 2], [1, 3]], np.float32))
    np.testing.assert_array_equal(got["scalar_vec"], [7.5])
    assert all(v.dtype == np.float32 for v in got.values())


def test_reader_names_the_file_for_zip_truncated_and_foreign_files(tmp_path: Path) -> None:
    z = tmp_path / "new.pt"
    with zipfile.ZipFile(z, "w") as f:
        f.writestr("archive/data.pkl", b"\x80\x02}q\x00.")
    with pytest.raises(authors.LegacyPtError, match=rf"{z}: a zip-format torch file"):
        authors.read_legacy_pt(z)
    good = tmp_path / "good.pt"
    write_legacy_pt(good, {"w": _contiguous("0", np.ones((8, 8), np.float32))})
    data = good.read_bytes()
    short = tmp_path / "short.pt"
    short.write_bytes(data[:-10])  # the raw storage cut short
    with pytest.raises(authors.LegacyPtError, match=rf"{short}: truncated"):
        authors.read_legacy_pt(short)
    short.write_bytes(data[:40])  # inside the pickles
    with pytest.raises(authors.LegacyPtError, match=rf"{short}: not a readable legacy torch"):
        authors.read_legacy_pt(short)
    evil = tmp_path / "evil.pt"
    # A GLOBAL opcode naming os.system, written by hand: pickling a live function would name
    # wherever it lives now (ray, once imported in this worker, replaces builtins.print).
    foreign = b"\x80\x02cos\nsystem\nq\x00."
    evil.write_bytes(_dump(authors.LEGACY_MAGIC) + _dump(1001) + _dump({}) + foreign)
    with pytest.raises(authors.LegacyPtError, match=r"unexpected global os\.system"):
        authors.read_legacy_pt(evil)
    other = tmp_path / "magic.pt"
    other.write_bytes(_dump(12345))
    with pytest.raises(authors.LegacyPtError, match=rf"{other}: magic number 12345"):
        authors.read_legacy_pt(other)
    with pytest.raises(authors.LegacyPtError, match="no such file"):
        authors.read_legacy_pt(tmp_path / "absent.pt")


# ------------------------------------------------------------ the importer (written files)


def test_import_writes_a_population_directory(
    fake_checkout: tuple[Path, dict[str, Any]], fake_population: Path, tmp_path: Path
) -> None:
    _, states = fake_checkout
    manifest = json.loads((fake_population / "manifest.json").read_text())
    assert manifest["env"] == "spread" and manifest["config"] == {"dynamics": "authors"}
    assert "do not redistribute" in manifest["provenance"]["licence"]
    assert manifest["provenance"]["repository"].endswith("conor-wallace/agent-transformer")
    assert len(manifest["provenance"]["files"]) == 8
    members = manifest["default"]["members"]
    assert [m["name"] for m in members] == list(authors.LEARNED)
    assert {(m["arch"], m["act"]) for m in members} == {("authors-ppo", "argmax")}
    teams = [tuple(t["slots"]) for t in manifest["default"]["teams"]]
    assert teams == README_TEAMS
    # The stored weights, through our wiring, give their logits in our action order.
    params = learned.load_params("spread", "default", fake_population)
    obs = np.random.default_rng(2).normal(size=(64, 18)).astype(np.float32)
    for m in members:
        fn = jax.vmap(authors.authors_logits(params[m["name"]], m, "spread"))
        ours = np.asarray(fn(jnp.asarray(obs)))
        theirs = _numpy_logits(states[m["name"]], obs)[:, FORK_TO_OURS]
        np.testing.assert_allclose(ours, theirs, atol=1e-4, rtol=1e-4)
    # The folder holding the files directly works too; a missing file names the paths.
    flat = tmp_path / "flat"
    flat.mkdir()
    for f in (fake_checkout[0] / authors.SPREAD_SUBDIR).iterdir():
        (flat / f.name).write_bytes(f.read_bytes())
    authors.import_spread(flat, tmp_path / "pop2")
    assert learned.directory_digest(tmp_path / "pop2") == learned.directory_digest(fake_population)
    (flat / "params_mappo_agent_3.pt").unlink()
    with pytest.raises(FileNotFoundError, match=r"pretrained_parameters/spread/params_.*mappo_"):
        authors.import_spread(flat, tmp_path / "pop3")
    import transam

    inside = Path(transam.__file__).parent / "partners" / "data" / "authors"
    with pytest.raises(ValueError, match="inside the transam package"):
        authors.import_spread(fake_checkout[0], inside)
    assert not inside.exists()


def test_import_authors_command(
    fake_checkout: tuple[Path, dict[str, Any]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "imported"
    main(["partners", "import-authors", "spread", str(fake_checkout[0]), "--out", str(out)])
    text = capsys.readouterr().out
    assert "13 teams" in text and "do not" in text and (out / "default.safetensors").exists()
    with pytest.raises(SystemExit, match="params_"):
        main(["partners", "import-authors", "spread", str(tmp_path / "none"), "--out", str(out)])


# ------------------------------------------------------------ population directories


def test_make_env_plays_a_population_directory(fake_population: Path) -> None:
    env = make_env("spread", partners=fake_population)
    assert env.population.name == "spread-authors" and env.num_partners == 13
    assert env.population.team_names[0] == "after_first_landmark+ippo_1"
    _, ts = make_random_rollout(env, 4, 50)(jax.random.key(0))
    assert np.isfinite(np.asarray(ts.reward)).all()
    # Partner-blind fields may change; the dynamics it was made for may not.
    make_env("spread", SpreadConfig(episode_len=5), partners=str(fake_population))
    with pytest.raises(EnvError, match=r"dynamics='mpe2' \(made for 'authors'\)"):
        make_env("spread", SpreadConfig(dynamics="mpe2"), partners=str(fake_population))
    with pytest.raises(EnvError, match=r"is for env 'spread', not 'tag'"):
        make_env("tag", partners=str(fake_population))


def test_envs_commands_take_a_population_directory(
    fake_population: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A directory plays only the env it was made for; --agent landmark is Spread's rule."""
    pop = str(fake_population)
    main(["envs", "list", "--partners", pop])
    assert "Population 'spread-authors'" in capsys.readouterr().out
    main(["envs", "rollout", "--partners", pop, "--agent", "landmark", "--episodes", "1"])
    text = capsys.readouterr().out
    assert "landmark controlled agent" in text and "mappo_2+ippo_3" in text
    with pytest.raises(SystemExit, match=r"is for env 'spread'; pass --envs spread"):
        main(["envs", "bench", "--partners", pop, "--envs", "tag"])
    with pytest.raises(SystemExit, match=r"--agent landmark is a Spread rule"):
        main(["envs", "rollout", "--envs", "lbf", "--agent", "landmark"])


def test_bad_partners_value_names_it_the_choices_and_the_directory_format(
    tmp_path: Path,
) -> None:
    msg = r"unknown partners 'nope'; valid choices: default, heldout, heuristic, or a population"
    with pytest.raises(EnvError, match=msg):
        make_env("spread", partners="nope")
    with pytest.raises(ConfigError, match=msg):
        TrainConfig(partners="nope").validate()
    with pytest.raises(SystemExit, match=r"unknown partners 'nope'.*manifest\.json"):
        main(["train", "--partners", "nope", "--out", str(tmp_path / "r")])
    with pytest.raises(EnvError, match=r"is a directory without manifest\.json"):
        make_env("spread", partners=str(tmp_path))
    assert not (tmp_path / "r").exists()


def test_train_and_evaluate_with_a_population_directory(
    fake_checkout: tuple[Path, dict[str, Any]], tmp_path: Path
) -> None:
    pop = tmp_path / "pop"
    authors.import_spread(fake_checkout[0], pop)
    out = tmp_path / "run"
    args = ["train", "--env", "spread", "--method", "nam", "--partners", str(pop)]
    args += ["--total-steps", "100", "--out", str(out), "--no-progress", "--a2c.num-envs", "2"]
    main([*args, "--eval.every-episodes", "2", "--eval.episodes", "4"])
    recorded = json.loads((out / "partners.json").read_text())
    assert recorded == {
        "env": "spread",
        "partners": str(pop.resolve()),
        "digest": learned.directory_digest(pop),
    }
    from transam.evaluation.final import evaluate_run

    res = evaluate_run(out, episodes=13, partners="train")
    assert res["population_name"] == "spread-authors"
    assert res["population_digest"] == res["trained_population_digest"] == recorded["digest"]
    assert (out / "eval_train.json").exists()
    other = evaluate_run(out, episodes=13, partners=str(pop))
    assert other["return"] == res["return"] and (out / "eval_pop-pop.json").exists()
    # --resume refuses a changed directory.
    cfg = TrainConfig(
        env="spread",
        method="nam",
        partners=str(pop),
        total_steps=100,  # the settings of the run above: its compiled programs are reused
        out=str(tmp_path / "run2"),
        progress=False,
        a2c=A2CConfig(num_envs=2),
        eval=EvalConfig(every_episodes=2, episodes=4),
    )
    assert not train(cfg, stop_after_chunks=1).finished
    manifest = json.loads((pop / "manifest.json").read_text())
    manifest["default"]["teams"] = manifest["default"]["teams"][:5]
    (pop / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(RunDirError, match=r"population .*pop' changed.*the directory as it was"):
        train(dataclasses.replace(cfg, resume=True))


# ------------------------------------------------------------ against the authors' files


@pytest.fixture(scope="module")
def authors_population(tmp_path_factory: pytest.TempPathFactory) -> Path:
    ref = _need_reference()
    out = tmp_path_factory.mktemp("authors") / "spread-authors"
    authors.import_spread(ref, out)
    return out


def test_imported_members_match_their_loader(authors_population: Path) -> None:
    """Each learned member's logits within 1e-5 of theirs (our action order), argmax exact;
    the heuristics exact; the team table as the README's (as executed)."""
    ref = np.load(REFERENCE / "reference_io.npz")
    obs = jnp.asarray(ref["obs_f32"])
    key = jax.random.key(0)
    entry = learned.read_population_dir(authors_population)["default"]
    params = learned.load_params("spread", "default", authors_population)
    pop = learned.directory_population("spread", authors_population)
    members = {m.name: m for m in pop.members}
    for m in entry["members"]:
        name = m["name"]
        logits = np.asarray(jax.vmap(authors.authors_logits(params[name], m, "spread"))(obs))
        # 1e-5 plus float32 rounding of logits up to ~20 (2e-5 there): torch and XLA sum in
        # other orders; the README's float64 recomputation itself differs from theirs by 1.3e-5.
        np.testing.assert_allclose(
            logits, ref[f"{name}_logits"][:, FORK_TO_OURS], atol=1e-5, rtol=1e-6, err_msg=name
        )
        acts = np.asarray(jax.vmap(members[name].act, in_axes=(None, 0))(key, obs))
        np.testing.assert_array_equal(acts, FORK_TO_OURS[ref[f"{name}_action"]], name)
    for name in authors.MEMBER_LIST[:5]:
        acts = np.asarray(jax.vmap(members[name].act, in_axes=(None, 0))(key, obs))
        np.testing.assert_array_equal(acts, FORK_TO_OURS[ref[f"heur_{name}_action"]], name)
    assert [t.slots for t in pop.teams] == README_TEAMS
    assert {m["name"]: m["sha256"][:16] for m in entry["members"]}["ippo_0"] == "7632b2943f728d29"


ACCEPTANCE_ENVS, ACCEPTANCE_EPISODES = 64, 16  # 1,024 episodes: standard errors 0.26 / 0.35


def test_acceptance_landmark_and_random_agents_against_the_authors_population(
    authors_population: Path,
) -> None:
    """fidelity.md: in their loop the landmark rule scores -49.1 and a random agent -58.7
    against their population (on the default Spread, the authors' dynamics)."""
    env = make_env("spread", partners=authors_population)
    steps = ACCEPTANCE_EPISODES * env.spec.episode_len
    landmark = make_random_rollout(env, ACCEPTANCE_ENVS, steps, landmark_agent)
    random = make_random_rollout(env, ACCEPTANCE_ENVS, steps)
    got_landmark = episode_stats(landmark(jax.random.key(0))[1]).returns
    got_random = episode_stats(random(jax.random.key(0))[1]).returns
    assert len(got_landmark) == len(got_random) == ACCEPTANCE_ENVS * ACCEPTANCE_EPISODES
    assert abs(got_landmark.mean() - (-49.0)) < 1.5, got_landmark.mean()
    assert abs(got_random.mean() - (-58.7)) < 2.0, got_random.mean()
