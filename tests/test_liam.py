"""Tag's default population is LIAM's: shipped weights, heuristics, observation and team table
checked against LIAM's own outputs (tests/data/liam_tag_reference.npz, see tests/data/README.md).

Nothing here needs ../shared: the one test that re-runs the conversion from LIAM's exports
skips when that folder is absent.
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from transam import make_env
from transam.envs.tag import Config, TagGame
from transam.partners import learned, liam, tag

REFERENCE = np.load(Path(__file__).parent / "data" / "liam_tag_reference.npz")
LIAM_EXPORTS = Path(__file__).resolve().parents[2] / "shared" / "reference" / "liam-tag"
KEY = jax.random.PRNGKey(0)
OURS = liam.TO_OURS  # LIAM action a is our action OURS[a] (the permutation is self-inverse)


def shipped_default() -> tuple[list[dict], dict]:
    entry = learned.load_manifest("tag")["default"]
    return entry["members"], learned.load_params("tag", "default")


def logits_of(member: dict, params: dict, obs: np.ndarray) -> np.ndarray:
    fn = learned.ARCHITECTURES[member["arch"]](params[member["name"]], member, "tag")
    return np.asarray(jax.jit(jax.vmap(fn))(jnp.asarray(obs)))


def test_every_learned_default_member_reproduces_liams_outputs() -> None:
    """IA2C: LIAM's softmax within 1e-5; MADDPG: its logits within 1e-5 and the same argmax on
    every row (in our action numbering: LIAM's columns permuted)."""
    members, params = shipped_default()
    assert sorted(m["name"] for m in members) == [
        *(f"ia2c_{i}" for i in range(3)),
        *(f"maddpg_{i}" for i in range(3)),
    ]
    obs = REFERENCE["obs_f32"]
    for m in members:
        logits = logits_of(m, params, obs)
        if m["arch"] == "liam-ia2c":
            probs = np.asarray(jax.nn.softmax(logits))
            want = REFERENCE[f"{m['name']}_probs"][:, OURS]
            np.testing.assert_allclose(probs, want, atol=1e-5, err_msg=m["name"])
        else:
            assert m["arch"] == "liam-maddpg", m
            want = REFERENCE[f"{m['name']}_logits"][:, OURS]
            np.testing.assert_allclose(logits, want, atol=1e-5, err_msg=m["name"])
            np.testing.assert_array_equal(
                logits.argmax(-1), OURS[REFERENCE[f"{m['name']}_action"]], err_msg=m["name"]
            )


def test_heuristics_reproduce_liams_outputs() -> None:
    """Exact on every row; after_pred (a coin per step) gives one of its two fixed-coin actions,
    and both over many keys."""
    obs = jnp.asarray(REFERENCE["obs"])
    for name in ("after_prey", "after_agent_far", "after_agent_close"):
        got = np.asarray(jax.vmap(getattr(tag, name), in_axes=(None, 0))(KEY, obs))
        np.testing.assert_array_equal(got, OURS[REFERENCE[f"heur_{name}_action"]], err_msg=name)
    keys = jax.random.split(KEY, 32)
    got = np.asarray(jax.vmap(jax.vmap(tag.after_pred, (None, 0)), (0, None))(keys, obs))
    to_a = OURS[REFERENCE["heur_after_pred_target8_action"]]
    to_b = OURS[REFERENCE["heur_after_pred_target10_action"]]
    assert ((got == to_a) | (got == to_b)).all()
    differ = to_a != to_b
    assert differ.sum() > 10
    assert ((got == to_a).any(0) & (got == to_b).any(0))[differ].all()


def test_predator_observation_has_liams_layout() -> None:
    """From the rows where two or three predators saw the same state, rebuild that state (every
    position, and the velocities known) and check that our Tag observes what LIAM's did: same
    16 floats in the same order with the same signs, so the nets take ours unchanged."""
    groups: dict[tuple, list[int]] = defaultdict(list)
    for r, key in enumerate(zip(*(REFERENCE[k] for k in ("source", "episode", "t")), strict=True)):
        groups[tuple(int(x) for x in key)].append(r)
    shared = [rows for rows in groups.values() if len(rows) > 1]
    assert len(shared) >= 8
    game = TagGame(Config())
    observe = jax.jit(game.observe)
    for rows in shared:
        o = REFERENCE["obs"][rows[0]]
        me = int(REFERENCE["agent_index"][rows[0]])
        lo, hi = (k for k in range(3) if k != me)
        pos, vel = np.zeros((6, 2)), np.zeros((6, 2))
        pos[[me, lo, hi, 3, 4, 5]] = o[2:4] + np.stack(
            [np.zeros(2), o[8:10], o[10:12], o[12:14], o[4:6], o[6:8]]
        )
        vel[3] = o[14:16]
        for r in rows:
            vel[REFERENCE["agent_index"][r]] = REFERENCE["obs"][r][:2]
        state = game.reset(KEY).replace(
            p_pos=jnp.asarray(pos, jnp.float32), p_vel=jnp.asarray(vel, jnp.float32)
        )
        preds = np.asarray(observe(state)[1])
        for r in rows:
            got = preds[REFERENCE["agent_index"][r]]
            np.testing.assert_allclose(got, REFERENCE["obs"][r], atol=1e-6, err_msg=f"row {r}")


# LIAM's member list and its 10 x 3 index table, as executed (pretrained_predators.py l. 149-162).
LIAM_MEMBERS = (
    "after_prey",
    "after_agent_far",
    "after_agent_close",
    "after_pred",
    "ia2c_0",
    "ia2c_1",
    "ia2c_2",
    "maddpg_0",
    "maddpg_1",
    "maddpg_2",
)
LIAM_INDEX = (
    (1, 8, 0),
    (2, 5, 8),
    (3, 0, 1),
    (8, 8, 9),
    (6, 0, 1),
    (7, 3, 4),
    (7, 1, 2),
    (3, 7, 3),
    (9, 3, 5),
    (0, 4, 6),
)


def test_default_population_is_liams_table_as_executed() -> None:
    pop = make_env("tag").population
    assert pop.name == "tag-default" and pop.size == 10 and pop.num_others == 3
    assert pop.team_names == tuple(f"liam{i}" for i in range(10))
    want = [tuple(LIAM_MEMBERS[i] for i in row) for row in LIAM_INDEX]
    assert [t.slots for t in pop.teams] == want
    assert [tuple(pop.members[i].name for i in row) for row in pop.table] == want
    kinds = {m.name: m.kind for m in pop.members}
    assert {n for n, k in kinds.items() if k == "heuristic"} == set(LIAM_MEMBERS[:4])
    assert {kinds[f"ia2c_{i}"] for i in range(3)} == {"ia2c:liam"}
    assert {kinds[f"maddpg_{i}"] for i in range(3)} == {"maddpg:liam"}
    # The held-out population is ours, in the same table where LIAM has learned predators.
    held = make_env("tag", partners="heldout").population
    assert held.team_names == pop.team_names
    to_ours = {f"ia2c_{i}": f"rl_a{i}" for i in range(3)} | {
        f"maddpg_{i}": f"rl_b{i}" for i in range(3)
    }
    assert [t.slots for t in held.teams] == [tuple(to_ours.get(s, s) for s in t) for t in want]


def test_ia2c_members_sample_and_maddpg_members_play_the_argmax() -> None:
    members, params = shipped_default()
    pop = {m.name: m for m in make_env("tag").population.members}
    obs = jnp.asarray(REFERENCE["obs_f32"])
    keys = jax.random.split(KEY, 256)
    for m in members:
        acts = np.asarray(jax.vmap(jax.vmap(pop[m["name"]].act, (None, 0)), (0, None))(keys, obs))
        logits = logits_of(m, params, REFERENCE["obs_f32"])
        if m["act"] == "argmax":
            assert m["arch"] == "liam-maddpg"
            assert (acts == logits.argmax(-1)).all(), m["name"]
            continue
        assert (m["arch"], m["act"]) == ("liam-ia2c", "sample")
        probs = np.asarray(jax.nn.softmax(logits))
        unsure = probs.max(-1) < 0.8
        assert unsure.sum() >= 4
        assert all(len(set(acts[:, r])) > 1 for r in np.flatnonzero(unsure)), m["name"]
        # the draws follow LIAM's distribution on the least certain row
        r = int(probs.max(-1).argmin())
        freq = np.bincount(acts[:, r], minlength=5) / len(keys)
        np.testing.assert_allclose(freq, probs[r], atol=0.1, err_msg=m["name"])


def test_manifest_names_liams_source_and_licence() -> None:
    entry = learned.load_manifest("tag")["default"]
    src = entry["source"]
    assert src["repository"] == "uoe-agents/LIAM"
    assert src["commit"] == "8545b9e4237eb60ad45b7cb8ed6caec6bc4263b5"
    assert src["license"] == "MIT"
    assert "Autonomous Agents Research Group (University of Edinburgh)" in src["copyright"]
    text = (learned.data_dir("tag") / src["license_file"]).read_text()
    assert text.startswith("MIT License") and src["copyright"] in text
    assert "included in all\ncopies or substantial portions of the Software." in text
    assert "no-op, 1 -x, 2 +x" in entry["action_order"]
    pyproject = (Path(__file__).parents[1] / "pyproject.toml").read_text()
    assert '"partners/data/*/LICENSE-*"' in pyproject  # the licence ships with the weights


def fake_exports(folder: Path, rng: np.random.Generator) -> dict[str, dict[str, np.ndarray]]:
    """Random weights in the shapes of LIAM's exports (what ``import_liam`` reads)."""
    out = {}
    for algo in liam.ALGOS:
        for i in range(3):
            p = {
                f"{n}.{part}": rng.normal(scale=0.3, size=shape if part == "weight" else shape[:1])
                for n, shape in liam.LAYERS[algo]
                for part in ("weight", "bias")
            }
            if algo == "maddpg":
                p |= {f"in_fn.{k}": rng.normal(size=16) for k in ("weight", "bias", "running_mean")}
                p["in_fn.running_var"] = rng.uniform(0.5, 2.0, 16)
                p["in_fn.eps"] = np.float32(1e-5)
            p = {k: np.asarray(v, np.float32) for k, v in p.items()}
            np.savez(folder / f"params_{algo}_agent_{i}.npz", **p)
            out[f"{algo}_{i}"] = p
    (folder / "LICENSE").write_text("MIT License\n\nCopyright (c) test\n")
    return out


def liam_forward(p: dict[str, np.ndarray], x: np.ndarray) -> np.ndarray:
    """LIAM's forward passes in numpy, in LIAM's action numbering."""
    dense = lambda n, h: h @ p[f"{n}.weight"].T + p[f"{n}.bias"]
    if "in_fn.weight" in p:
        x = (x - p["in_fn.running_mean"]) / np.sqrt(p["in_fn.running_var"] + 1e-5)
        x = x * p["in_fn.weight"] + p["in_fn.bias"]
        h = np.maximum(dense("fc2", np.maximum(dense("fc1", x), 0)), 0)
        return dense("fc3", h)
    h = np.maximum(dense("fc2", np.maximum(dense("fc1", x), 0)), 0)
    return dense("policy", h)


def test_import_permutes_the_output_rows_into_our_action_order(tmp_path: Path) -> None:
    src, root = tmp_path / "liam", tmp_path / "out"
    src.mkdir()
    raw = fake_exports(src, np.random.default_rng(0))
    path = liam.import_liam(src, root)
    assert (root / liam.LICENSE_FILE).read_text() == (src / "LICENSE").read_text()
    entry = json.loads(path.read_text())["default"]
    params = learned.load_params("tag", "default", root)
    obs = np.random.default_rng(1).normal(size=(32, 16)).astype(np.float32)
    for m in entry["members"]:
        got = logits_of(m, params, obs)
        want = liam_forward(raw[m["name"]], obs)
        np.testing.assert_allclose(got, want[:, liam.TO_OURS], atol=1e-4)
        # +x in LIAM's numbering (1) is +x in ours (2)
        np.testing.assert_allclose(got[:, 2], want[:, 1], atol=1e-4)
    assert learned.population("tag", "default", root).team_names == tuple(
        f"liam{i}" for i in range(10)
    )


def test_import_and_liam_builders_name_bad_input(tmp_path: Path) -> None:
    src = tmp_path / "liam"
    src.mkdir()
    fake_exports(src, np.random.default_rng(0))
    (src / "params_maddpg_agent_2.npz").unlink()
    with pytest.raises(FileNotFoundError, match=r"missing params_maddpg_agent_2\.npz"):
        liam.convert(src)
    fake_exports(src, np.random.default_rng(0))
    bad = dict(np.load(src / "params_ia2c_agent_1.npz"))
    bad["fc2.weight"] = bad["fc2.weight"][:, :32]
    np.savez(src / "params_ia2c_agent_1.npz", **bad)
    with pytest.raises(ValueError, match=r"fc2\.weight should have shape \(64, 64\), got"):
        liam.convert(src)
    (src / "LICENSE").unlink()
    with pytest.raises(FileNotFoundError, match="missing LICENSE"):
        liam.import_liam(src, tmp_path / "out")
    members, params = shipped_default()
    with pytest.raises(ValueError, match="LIAM's predators play env 'tag', not 'spread'"):
        learned.member_policy(params[members[0]["name"]], members[0], "spread")


@pytest.mark.skipif(
    not LIAM_EXPORTS.is_dir(), reason=f"LIAM's exported weights not found at {LIAM_EXPORTS}"
)
def test_shipped_weights_are_the_conversion_of_liams_exports(tmp_path: Path) -> None:
    """The shipped safetensors is byte for byte what ``transam partners import-liam`` makes."""
    liam.import_liam(LIAM_EXPORTS, tmp_path)
    shipped = learned.data_dir("tag")
    assert (tmp_path / "default.safetensors").read_bytes() == (
        shipped / "default.safetensors"
    ).read_bytes()
    assert (tmp_path / liam.LICENSE_FILE).read_bytes() == (shipped / liam.LICENSE_FILE).read_bytes()
    made = learned.load_manifest("tag", tmp_path)["default"]
    kept = learned.load_manifest("tag")["default"]
    assert made == {k: v for k, v in kept.items() if k != "diversity"}
