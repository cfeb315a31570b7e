"""The reproduction grid's planning and bookkeeping (no training here: see test_reproduce.py)."""

from __future__ import annotations

import json
import os

import pytest

from transam import registry
from transam.compose import make_env
from transam.reproduce import grid
from transam.train.config import ConfigError
from transam.train.presets import parse_settings
from transam.train.programs import make_plan


@pytest.mark.parametrize("name", registry.PAPER_ENVS)
def test_episode_lengths_match_the_environments(name: str) -> None:
    assert (
        registry.env_entry(name).episode_len
        == make_env(name, partners="heuristic").spec.episode_len
    )


def test_the_machine_record_names_the_cpu_a_masked_model_name_hides() -> None:
    two = "processor\t: 0\nmodel name\t: Intel(R) Xeon(R) Processor\ncpu family\t: 6\n"
    two += "model\t\t: 167\nstepping\t: 1\nflags\t\t: fpu avx2 fma avx512f amx_tile\n\n"
    two += "processor\t: 1\nmodel name\t: other\nflags\t\t: sse\n"
    assert grid.cpu_description(two) == {
        "cpu": "Intel(R) Xeon(R) Processor (family/model/stepping 6/167/1)",
        "cpu_isa": ["avx2", "fma", "avx512f", "amx_tile"],
    }
    assert grid.cpu_description("") == {}
    assert grid.machine()["cpus"] == os.cpu_count()


@pytest.mark.parametrize("budget", list(grid.BUDGETS))
@pytest.mark.parametrize("name", registry.PAPER_ENVS)
def test_run_config_evaluates_about_budget_evals_times(budget: str, name: str) -> None:
    b = grid.BUDGETS[budget]
    config = grid.run_config(grid.RunSpec(name, "nam", 3), b, "somewhere")
    plan = make_plan(config, registry.env_entry(name).episode_len)
    assert config.seed == 3 and config.total_steps == b.total_steps
    assert config.eval.episodes == b.eval_episodes
    assert config.run_dir == f"somewhere/runs/{name}/nam/seed_3"
    # evenly spaced evaluation points: the budget's count, give or take rounding
    assert abs(len(plan.chunks) - b.evals) <= max(1, b.evals // 4)


def test_grid_specs_order_and_errors() -> None:
    specs = grid.grid_specs(["spread", "tag"], ["nam", "liam"], [0, 1])
    assert [s.rel for s in specs[:3]] == [
        "runs/spread/nam/seed_0",
        "runs/spread/nam/seed_1",
        "runs/spread/liam/seed_0",
    ]
    assert grid.spec_from_rel(specs[-1].rel) == specs[-1]
    with pytest.raises(ConfigError, match=r"unknown env 'pong'.*tag, spread"):
        grid.grid_specs(["pong"], ["nam"], [0])
    with pytest.raises(ConfigError, match=r"unknown method 'lima'.*transam"):
        grid.grid_specs(["tag"], ["lima"], [0])
    with pytest.raises(ConfigError, match="distinct"):
        grid.grid_specs(["tag"], ["nam"], [0, 0])
    with pytest.raises(ConfigError, match="empty"):
        grid.grid_specs(["tag"], [], [0])


def test_grid_file_keeps_one_budget_and_never_adopts_a_foreign_directory(tmp_path) -> None:
    out = tmp_path / "g"
    specs = grid.grid_specs(["spread"], ["nam"], [0])
    grid.open_grid(out, "smoke", specs, ["transam", "reproduce"])
    more = grid.grid_specs(["spread"], ["nam", "liam"], [0])
    grid.open_grid(out, "smoke", more, ["again"])  # extending the same budget is fine
    grid.close_grid(out, ["x: failed"])
    saved = json.loads((out / "grid.json").read_text())
    assert saved["runs"] == ["runs/spread/nam/seed_0", "runs/spread/liam/seed_0"]
    assert [i["argv"] for i in saved["invocations"]] == [["transam", "reproduce"], ["again"]]
    assert saved["invocations"][-1]["failures"] == ["x: failed"]
    assert saved["invocations"][-1]["wall_s"] >= 0
    with pytest.raises(ConfigError, match=r"holds a 'smoke' grid"):
        grid.open_grid(out, "small", specs, [])
    with pytest.raises(ConfigError, match=r"unknown budget 'huge'.*smoke, small, medium, paper"):
        grid.open_grid(tmp_path / "h", "huge", specs, [])
    other = tmp_path / "other"
    other.mkdir()
    (other / "precious.txt").write_text("keep")
    with pytest.raises(ConfigError, match="not empty"):
        grid.open_grid(other, "smoke", specs, [])
    assert (other / "precious.txt").read_text() == "keep"


def test_a_grid_keeps_one_partner_population_and_its_runs_train_against_it(tmp_path) -> None:
    out = tmp_path / "g"
    specs = grid.grid_specs(["spread"], ["nam"], [0])
    assert grid.grid_partners(out) == "default"  # no grid yet
    grid.open_grid(out, "smoke", specs, ["transam"], partners="heldout")
    assert grid.grid_partners(out) == "heldout"
    assert json.loads((out / "grid.json").read_text())["partners"] == "heldout"
    config = grid.run_config(specs[0], grid.BUDGETS["smoke"], out, grid.grid_partners(out))
    assert config.partners == "heldout"
    with pytest.raises(ConfigError, match=r"against partners 'heldout'; use another --out"):
        grid.open_grid(out, "smoke", specs, [], partners="default")
    old = tmp_path / "old"  # a grid.json written before the entry existed
    grid.open_grid(old, "smoke", specs, [])
    saved = json.loads((old / "grid.json").read_text())
    del saved["partners"]
    (old / "grid.json").write_text(json.dumps(saved))
    assert grid.grid_partners(old) == "default"
    grid.open_grid(old, "smoke", specs, [])  # resumes as the default population


def test_reproduce_refuses_an_unknown_population_before_writing(tmp_path) -> None:
    from transam.cli import main

    out = tmp_path / "g"
    with pytest.raises(SystemExit, match="unknown partners 'nope'; valid choices: default"):
        main(["reproduce", "--budget", "smoke", "--out", str(out), "--partners", "nope"])
    assert not out.exists()


def test_local_grid_stops_on_sigterm(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    """SIGTERM to a grid with --jobs 2 (e.g. `kill` of the `transam reproduce` process, whose
    workers it used to leave training) stops it as it stops one run: the signal reaches each
    run in flight once, those runs stop as at a chunk's end, no other run starts, and the grid
    raises RunInterrupted (the CLI then exits 143: rerunning resumes). Real worker processes,
    with a task that waits for the stop request instead of training."""
    import multiprocessing as mp
    import signal
    import threading
    import time

    from grid_stop_task import wait_for_stop

    from transam.train.stop import RunInterrupted

    assert threading.current_thread() is threading.main_thread()  # where signals are caught
    monkeypatch.setattr(grid, "_run_group_in_subprocess", wait_for_stop)
    specs = [grid.RunSpec("spread", "nam", s) for s in range(4)]
    before = signal.getsignal(signal.SIGTERM)

    def terminate_when_two_started() -> None:
        deadline = time.monotonic() + 120
        while len(list(tmp_path.glob("started-*"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=terminate_when_two_started, daemon=True).start()
    with pytest.raises(RunInterrupted, match="SIGTERM: the grid stopped") as stopped:
        grid.run_local(tmp_path, specs, grid.BUDGETS["smoke"], jobs=2)
    assert stopped.value.signum == signal.SIGTERM
    started = sorted(p.name.removeprefix("started-") for p in tmp_path.glob("started-*"))
    assert len(started) == 2  # the other two never started
    assert sorted(p.name.removeprefix("stopped-") for p in tmp_path.glob("stopped-*")) == started
    assert not mp.active_children()  # the pool is gone: no worker left training
    assert signal.getsignal(signal.SIGTERM) == before  # restored


def test_local_grid_hands_out_one_run_at_a_time(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    """With --jobs > 1 each run is its own task, first seeds first: a method's later seeds do
    not wait behind its first while another process idles (the tail of the 2026-12 medium
    grid), and start once its programs are in the compilation cache."""
    import concurrent.futures
    from typing import Any

    submitted: list[list[str]] = []

    class Threads(concurrent.futures.ThreadPoolExecutor):
        def __init__(self, jobs: int, mp_context: object = None, initializer: Any = None) -> None:
            super().__init__(jobs)  # not the initializer: it gives a worker its own process group

        def submit(self, fn: Any, /, *args: Any, **kwargs: Any) -> Any:
            submitted.append([s.rel for s in args[2]])  # (_in_worker's) task, out, specs, ...
            return super().submit(fn, *args, **kwargs)

    def task(
        out: str, specs: list[grid.RunSpec], budget: grid.Budget, vmap_seeds: bool
    ) -> list[str]:
        assert os.environ["XLA_PYTHON_CLIENT_PREALLOCATE"] == "false"  # processes share a GPU
        return [f"{s.rel}: failed" for s in specs if s.seed == 2]

    monkeypatch.delenv("XLA_PYTHON_CLIENT_PREALLOCATE", raising=False)
    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", Threads)
    monkeypatch.setattr(grid, "_run_group_in_subprocess", task)
    specs = [grid.RunSpec("spread", m, s) for m in ("nam", "transam") for s in range(3)]
    failures = grid.run_local(tmp_path, specs, grid.BUDGETS["smoke"], jobs=2)
    assert submitted == [[s.rel] for k in range(3) for s in specs if s.seed == k]
    assert failures == [f"{s.rel}: failed" for s in specs if s.seed == 2]  # in grid order
    submitted.clear()  # --vmap-seeds: a method's seeds are one task
    failures = grid.run_local(tmp_path, specs, grid.BUDGETS["smoke"], jobs=2, vmap_seeds=True)
    assert submitted == [[s.rel for s in specs if s.method == m] for m in ("nam", "transam")]
    assert failures == [f"{s.rel}: failed" for s in specs if s.seed == 2]


def test_settings_parse_to_typed_values_and_bad_ones_are_named() -> None:
    settings = parse_settings(["a2c.z_scale=0.088", "model.dropout=0"])
    assert settings == {"a2c.z_scale": 0.088, "model.dropout": 0.0}
    assert type(settings["model.dropout"]) is float  # an integer given for a float setting
    assert parse_settings(["a2c.time-feature=false", "a2c.advantage=gae"]) == {
        "a2c.time_feature": False,
        "a2c.advantage": "gae",
    }
    for bad, message in (
        ("a2c.zscale=1", r"unknown setting 'a2c.zscale'; valid a2c settings: .*z_scale"),
        ("total_steps=3", r"GROUP.NAME=VALUE with GROUP one of a2c, model, baseline"),
        ("a2c.z_scale", r"GROUP.NAME=VALUE"),
        ("a2c.time_feature=3", r"'a2c.time_feature' takes a bool \(default True\), got '3'"),
        ("a2c.num_envs=2.5", r"'a2c.num_envs' takes a int \(default 10\), got '2.5'"),
        ("a2c.z_scale=-1", r"a2c.z_scale must be in \[0.0, inf\], got -1.0"),
        ("a2c.advantage=td", r"a2c.advantage.*'td'.*gae, recomputed"),
    ):
        with pytest.raises(ConfigError, match=message):
            parse_settings([bad])


def test_a_grid_keeps_one_set_of_settings_and_its_runs_train_with_them(tmp_path) -> None:
    out = tmp_path / "g"
    specs = grid.grid_specs(["overcooked"], ["transam"], [0])
    settings = {"a2c.z_scale": 0.088, "model.dropout": 0.0}
    assert grid.grid_settings(out) == {}  # no grid yet
    grid.open_grid(out, "smoke", specs, ["transam"], settings=settings)
    grid.open_grid(out, "smoke", specs, ["again"])  # an invocation without them keeps them
    assert grid.grid_settings(out) == settings
    config = grid.run_config(specs[0], grid.BUDGETS["smoke"], out, "default", settings)
    assert (config.a2c.z_scale, config.model.dropout) == (0.088, 0.0)
    assert grid.run_config(specs[0], grid.BUDGETS["smoke"], out).a2c.z_scale == 1.0
    saved = (out / "grid.json").read_text()
    with pytest.raises(ConfigError, match=r"settings a2c.z_scale=0.088 model.dropout=0.0; use"):
        grid.open_grid(out, "smoke", specs, [], settings={"a2c.z_scale": 0.5})
    assert (out / "grid.json").read_text() == saved
