"""The ``transam`` command on tiny settings: it runs, prints its tables, and rejects bad input."""

from __future__ import annotations

from pathlib import Path

import pytest

from transam import cli
from transam.cli import main
from transam.train import programs
from transam.train.config import TrainConfig


def test_envs_list_prints_every_environment(capsys: pytest.CaptureFixture[str]) -> None:
    main(["envs", "list"])
    out = " ".join(capsys.readouterr().out.split())  # undo rich's line wrapping
    for name in ("tag", "spread", "overcooked", "lbf"):
        assert f"Population '{name}-default'" in out  # the shipped learned population
    main(["envs", "list", "--partners", "heuristic"])
    assert "Population 'lbf-heuristic'" in " ".join(capsys.readouterr().out.split())


def test_envs_bench_prints_a_rate(capsys: pytest.CaptureFixture[str]) -> None:
    main(["envs", "bench", "--envs", "spread", "--num-envs", "8", "--steps", "5", "--repeats", "2"])
    out = capsys.readouterr().out
    assert "spread" in out and "median steps/s" in out


def test_envs_rollout_prints_per_team_returns(capsys: pytest.CaptureFixture[str]) -> None:
    main(["envs", "rollout", "--envs", "lbf", "--episodes", "2", "--num-envs", "16"])
    out = capsys.readouterr().out
    assert "lbf-default population" in out and "mean return" in out
    heldout = ["--partners", "heldout", "--episodes", "1", "--num-envs", "8"]
    main(["envs", "rollout", "--envs", "lbf", *heldout])
    assert "lbf-heldout population" in capsys.readouterr().out


def test_envs_rollout_plays_spreads_landmark_agent(capsys: pytest.CaptureFixture[str]) -> None:
    """``--agent landmark`` (Spread only) replaces the random controlled agent."""
    main(["envs", "rollout", "--envs", "spread", "--agent", "landmark", "--episodes", "1"])
    out = capsys.readouterr().out
    assert "landmark controlled agent" in out and "spread-default population" in out
    with pytest.raises(SystemExit, match="--agent landmark is a Spread rule; pass --envs spread"):
        main(["envs", "rollout", "--envs", "tag", "--agent", "landmark"])


def test_bad_values_are_rejected_with_the_valid_choices(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit):
        main(["envs", "bench", "--envs", "pong"])
    err = capsys.readouterr()
    assert "pong" in err.out + err.err and "spread" in err.out + err.err
    with pytest.raises(SystemExit, match="--num-envs must be >= 1, got 0"):
        main(["envs", "bench", "--num-envs", "0"])
    with pytest.raises(SystemExit, match=r"--window must be between 1 and .* 25 .*got 26"):
        main(["partners", "diversity", "spread", "--window", "26"])
    with pytest.raises(SystemExit, match=r"unknown partners '/nope'; valid choices: default"):
        main(["partners", "diversity", "spread", "--population", "/nope"])
    with pytest.raises(SystemExit, match=r"--population measures that directory's .* no --heldout"):
        main(["partners", "diversity", "spread", "--population", "/nope", "--heldout"])
    with pytest.raises(SystemExit, match=r"--heuristic .* takes none of --heldout, --record"):
        main(["partners", "diversity", "spread", "--heuristic", "--record"])
    with pytest.raises(SystemExit, match="--agent landmark is a Spread rule; pass ENV spread"):
        main(["partners", "diversity", "tag", "--agent", "landmark"])
    with pytest.raises(SystemExit, match=r"--levels-episodes must be >= 2 .* got 1"):
        main(["partners", "diversity", "spread", "--levels-episodes", "1"])
    with pytest.raises(SystemExit, match="--levels-steps must be >= 1, got 0"):
        main(["partners", "diversity", "spread", "--levels-steps", "0"])
    with pytest.raises(SystemExit, match="--agent landmark takes no --record"):
        main(["partners", "diversity", "spread", "--agent", "landmark", "--record"])
    with pytest.raises(SystemExit, match="--episodes must be at least 1, got 0"):
        main(["partners", "show", "tag", "--episodes", "0"])
    # Tag's default population is LIAM's, imported: training it is refused with the way out.
    with pytest.raises(SystemExit, match=r"imported, not trained: `transam partners import-liam"):
        main(["partners", "train", "tag"])


def test_partners_import_liam_names_what_is_missing(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match=rf"missing LICENSE in {tmp_path}"):
        main(["partners", "import-liam", "tag", str(tmp_path), "--out", str(tmp_path / "o")])
    (tmp_path / "LICENSE").write_text("MIT License\n")
    with pytest.raises(SystemExit, match=r"missing params_ia2c_agent_0\.npz"):
        main(["partners", "import-liam", "tag", str(tmp_path), "--out", str(tmp_path / "o")])


def test_demo_trains_and_compares_with_a_random_agent(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "demo"
    # The shipped runs' table is tested in test_evaluation.py and test_pretrained.py; here it
    # is left out, while the training programs compile ahead in a thread as they do beside it.
    shown: list[tuple[str, int]] = []
    monkeypatch.setattr(cli, "_print_showcase", lambda env, n: shown.append((env, n)))
    compiled: list[TrainConfig] = []
    ahead = programs.compile_ahead
    monkeypatch.setattr(programs, "compile_ahead", lambda c: (ahead(c), compiled.append(c)))
    # NAM keeps the compile short; TransAM's training path is tested in test_methods.py.
    args = ["demo", "--method", "nam", "--total-steps", "100", "--out", str(out), "--no-progress"]
    args.extend(["--pretrained-episodes", "3"])
    main([*args, "--a2c.num-envs", "2", "--eval.every-episodes", "2", "--eval.episodes", "4"])
    assert shown == [("spread", 3)]
    assert [(c.method, c.total_steps, c.a2c.num_envs) for c in compiled] == [("nam", 100, 2)]
    text = capsys.readouterr().out
    assert "final evaluation: spread / nam" in text and "uniformly random agent" in text
    assert (out / "final.json").exists() and len(
        (out / "metrics.jsonl").read_text().splitlines()
    ) == 2
