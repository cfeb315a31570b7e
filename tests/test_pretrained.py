"""The pretrained runs shipped in the package (src/transam/pretrained/): each one loads without
its run directory, was trained against the population shipped now, and plays better than a
random agent on the same episodes (and, with an agent model, predicts its partners' actions
better than the memoryless level)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from transam.evaluation.final import evaluate_run, random_returns
from transam.evaluation.weights import pretrained_dir, pretrained_names, read_card
from transam.models.base import ACC_NEWEST
from transam.partners.learned import population_digest
from transam.reproduce.report.results import partner_levels
from transam.rundir import load_run_config, recorded_population

EPISODES = 100  # the paired gain over random play: 3.8-5.7, standard error 0.64-0.68 (seed 11)
SEED = 11  # not the evaluation seeds the shipped run was chosen on (0 and 7)


def test_the_package_ships_a_pretrained_transam_for_spread() -> None:
    cards = {n: read_card(pretrained_dir(n)) for n in pretrained_names()}
    assert any(c["env"] == "spread" and c["method"] == "transam" for c in cards.values()), cards


@pytest.mark.parametrize("name", pretrained_names())
def test_shipped_run_beats_random_play_and_the_memoryless_level(name: str, tmp_path: Path) -> None:
    path = pretrained_dir(name)
    config = load_run_config(path)
    card = read_card(path)
    assert (card["env"], card["method"], card["partners"]) == (
        config.env,
        config.method,
        config.partners,
    )
    recorded = recorded_population(path)
    assert recorded is not None
    assert recorded["digest"] == population_digest(config.env, config.partners)  # not stale

    res = evaluate_run(name, EPISODES, seed=SEED, out=tmp_path)
    assert res["step"] == card["step"] and res["checkpoint"] == "params.safetensors"
    # the same episodes: test_evaluation checks the pairing (paired_random_returns)
    gain = np.asarray(res["returns"]) - random_returns(name, EPISODES, SEED)
    se = gain.std() / np.sqrt(EPISODES)
    assert gain.mean() > 2.5 * se, (gain.mean(), se)  # random play: 0 within its s.e.
    if ACC_NEWEST in res:
        levels = partner_levels([config.env])[config.env]
        assert levels is not None
        # past the two-step level: more than the partners' motion (the shipped TransAM: 0.63
        # against 0.57, on 1,000 episodes and on these 100)
        assert res[ACC_NEWEST] > levels["memoryless_own2_accuracy"] + 0.03, res[ACC_NEWEST]


def test_the_cli_lists_the_shipped_runs(capsys: pytest.CaptureFixture[str]) -> None:
    from transam.cli import main

    main(["pretrained"])
    text = capsys.readouterr().out
    for name in pretrained_names():
        assert name in text
        assert str(read_card(pretrained_dir(name))["step"]) in text.replace(",", "")
