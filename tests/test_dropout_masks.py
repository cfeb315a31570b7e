"""Packed dropout masks (``TransAMConfig.dropout_masks``): the drop rate and scaling are
flax's, masks are independent across entries and keys, the window model keeps flax's masks
(and so its numbers) by default, the streaming model packs, and bad values are refused."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import tyro
from local_data import random_rollout

from transam.compose import make_env
from transam.models import make_model
from transam.models.dropout import packed_dropout, packed_keep
from transam.models.transam import TransAMConfig
from transam.train.config import ADDED_SETTINGS, ConfigError, TrainConfig

TINY = TransAMConfig(width=32, layers=2, heads=2, ff_width=64)


@pytest.mark.parametrize("rate", [0.1, 0.5])
def test_packed_masks_drop_at_the_rate_independently(rate: float) -> None:
    n = 400_003  # not a multiple of 4: the last block is cut
    keep = np.asarray(packed_keep(jax.random.key(0), (n,), rate))
    se = np.sqrt(rate * (1 - rate) / n)
    assert abs((1 - keep.mean()) - rate) < 5 * se
    # Neighbours (the four draws of one block, and across blocks) are uncorrelated.
    a = keep.astype(float)
    for lag in (1, 2, 3, 4, 5):
        assert abs(np.corrcoef(a[:-lag], a[lag:])[0, 1]) < 5 / np.sqrt(n)
    # Same key, typed or raw: same mask; another key: another mask, as often different as
    # two independent masks are.
    assert np.array_equal(keep, np.asarray(packed_keep(jax.random.PRNGKey(0), (n,), rate)))
    other = np.asarray(packed_keep(jax.random.key(1), (n,), rate))
    assert abs(np.mean(keep != other) - 2 * rate * (1 - rate)) < 10 * se
    # Kept entries are scaled by 1 / (1 - rate): the mean is preserved.
    x = jnp.ones((1000, 400))
    y = np.asarray(packed_dropout(x, rate, jax.random.key(3)))
    np.testing.assert_allclose(np.unique(y), [0.0, 1 / (1 - rate)], rtol=1e-6)
    assert abs(y.mean() - 1.0) < 5 * np.sqrt(rate / (1 - rate) / x.size)


def test_models_use_their_masks() -> None:
    env = make_env("spread", partners="heuristic")
    xs, _, _ = random_rollout(env, jax.random.key(0), 1, 5)
    xs = jax.tree.map(lambda a: a[:, 0], xs)
    for attention, default in (("window", "flax"), ("stream", "packed")):
        base = dataclasses.replace(TINY, attention=attention)
        assert base.masks == default
        zs = {}
        for masks in ("flax", "packed"):
            model = make_model("transam", env.spec, dataclasses.replace(base, dropout_masks=masks))
            params = model.init(jax.random.key(1), env.spec)
            carry = model.init_carry(env.spec)
            embed = jax.jit(model.embed_rollout)
            zs[masks] = np.asarray(embed(params, carry, xs, jax.random.key(2)))
            # Without a key there is no dropout, whatever the masks.
            zs[masks, "det"] = np.asarray(embed(params, carry, xs))
        np.testing.assert_array_equal(zs["flax", "det"], zs["packed", "det"])
        assert not np.allclose(zs["flax"], zs["packed"])
        assert not np.allclose(zs["packed"], zs["packed", "det"])
        # The default is the resolved kind, mask for mask.
        model = make_model("transam", env.spec, base)
        params = model.init(jax.random.key(1), env.spec)
        z = jax.jit(model.embed_rollout)(params, model.init_carry(env.spec), xs, jax.random.key(2))
        np.testing.assert_array_equal(np.asarray(z), zs[default])


def test_settings_validation_and_old_runs() -> None:
    with pytest.raises(ConfigError, match=r"model\.dropout_masks.*'fast'.*flax"):
        TrainConfig(model=dataclasses.replace(TINY, dropout_masks="fast")).validate()  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="dropout_masks invalid"):
        make_model(
            "transam",
            make_env("spread", partners="heuristic").spec,
            dataclasses.replace(TINY, dropout_masks="fast"),
        )  # type: ignore[arg-type]
    cli = tyro.cli(TrainConfig, args=["--model.dropout-masks", "packed"])
    assert cli.model.masks == "packed"
    # Runs written before the setting existed drew flax's masks, streaming ones included.
    assert ADDED_SETTINGS["model", "dropout_masks"] == "flax"


@pytest.mark.parametrize(
    ("attention", "saved", "now", "resumes"),
    [
        ("window", "absent", None, True),  # a run from before the setting: flax's, as now
        ("stream", "absent", None, False),  # it drew flax's masks; the default now packs
        ("stream", "absent", "flax", True),  # ... and resumes when told flax
        ("window", None, "flax", True),  # started on the default, resumed naming it
        ("stream", None, "packed", True),
        ("window", None, "packed", False),
    ],
)
def test_resume_compares_the_masks_a_run_draws(
    tmp_path: Path, attention: str, saved: str | None, now: str | None, resumes: bool
) -> None:
    """--resume (and `transam reproduce`, which resumes with the grid's settings) matches
    masks by what the model draws, not by how the setting was spelled."""
    from transam.rundir import RunDirError, prepare_run_dir

    def config(masks: str | None) -> TrainConfig:
        model = dataclasses.replace(TINY, attention=attention, dropout_masks=masks)  # type: ignore[arg-type]
        return TrainConfig(model=model, out=str(tmp_path), resume=True)

    written = config(None if saved == "absent" else saved).identity()
    if saved == "absent":
        del written["model"]["dropout_masks"]
    (tmp_path / "config.json").write_text(json.dumps(written))
    if resumes:
        assert prepare_run_dir(config(now)) == "resume"
    else:
        with pytest.raises(RunDirError, match=r"model\.dropout_masks \(run: '(flax|packed)'"):
            prepare_run_dir(config(now))
