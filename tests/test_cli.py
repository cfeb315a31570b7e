"""The ``transam`` command on tiny settings: it runs, prints its tables, and rejects bad input."""

from __future__ import annotations

import pytest

from transam.cli import main


def test_envs_list_prints_every_environment(capsys: pytest.CaptureFixture[str]) -> None:
    main(["envs", "list"])
    out = capsys.readouterr().out
    for name in ("tag", "spread", "overcooked", "lbf"):
        assert name in out


def test_envs_bench_prints_a_rate(capsys: pytest.CaptureFixture[str]) -> None:
    main(["envs", "bench", "--envs", "spread", "--num-envs", "8", "--steps", "5", "--repeats", "2"])
    out = capsys.readouterr().out
    assert "spread" in out and "median steps/s" in out


def test_demo_prints_per_team_returns(capsys: pytest.CaptureFixture[str]) -> None:
    main(["demo", "--envs", "lbf", "--episodes", "2", "--num-envs", "16"])
    out = capsys.readouterr().out
    assert "lbf" in out and "mean return" in out


def test_bad_values_are_rejected_with_the_valid_choices(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit):
        main(["envs", "bench", "--envs", "pong"])
    err = capsys.readouterr()
    assert "pong" in err.out + err.err and "spread" in err.out + err.err
    with pytest.raises(SystemExit, match="--num-envs must be >= 1, got 0"):
        main(["envs", "bench", "--num-envs", "0"])
