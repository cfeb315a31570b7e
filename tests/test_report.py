"""`transam report` on synthetic grids (no training, no JAX compilation): the bootstrap, the
aggregation, every artefact, claim verdicts that follow the data, and partial grids."""

from __future__ import annotations

import io
import json
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import scipy.stats

from transam.cli import Report
from transam.registry import PAPER_ENVS, PAPER_METHODS, display
from transam.reproduce.report.build import build_report
from transam.reproduce.report.claims import combine
from transam.reproduce.report.load import read_pca
from transam.reproduce.report.markdown import fmt_stat
from transam.reproduce.report.stats import (
    bootstrap_ci,
    curve_ci,
    difference,
    interval,
    stratified_bootstrap,
    stratified_resample_indices,
)
from transam.train.config import ConfigError

ACTIONS = {"transam", "liam", "cail", "pel", "transam-fuse", "transam-pool", "transam-im"}
OBS = {"transam", "liam", "transam-fuse", "transam-pool"}
POSITIONS = {"transam", "transam-fuse", "transam-im"}  # decode every window position
BASE = {"tag": 0.0, "spread": -50.0, "overcooked": 40.0, "lbf": 0.5}
EPISODE = 8  # steps of a synthetic episode
CHUNKS = 4  # evaluation points of a synthetic training run


def _write_json(path: Path, obj: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj))


def write_grid(
    out: Path,
    ret: dict[str, float],
    acc: dict[str, float],
    envs: Iterable[str] = PAPER_ENVS,
    methods: Iterable[str] = PAPER_METHODS,
    seeds: Iterable[int] = (0, 1, 2),
    absent: Iterable[str] = (),
    unfinished: Iterable[str] = (),
    unevaluated: Iterable[str] = (),
    noise: float = 0.2,
    sizes: bool = True,
) -> None:
    """A grid directory as `transam reproduce` + `transam evaluate` would leave it: method m
    scores BASE[env] + ret[m] (+ noise) and action accuracy acc[m]; ``sizes``: its evaluations
    record the policy's input sizes (older ones do not). Runs named in ``absent``
    are listed in grid.json but have no directory; ``unfinished`` ones have no final.json;
    ``unevaluated`` ones have no eval_*.json."""
    rng = np.random.default_rng(0)
    rels = [f"runs/{e}/{m}/seed_{s}" for e in envs for m in methods for s in seeds]
    grid = {
        "budget": "smoke",
        "budget_settings": {"total_steps": 4000, "seeds": 3, "evals": CHUNKS},
        "runs": rels,
        "invocations": [
            {
                "argv": ["transam", "reproduce", "--budget", "smoke", "--out", str(out)],
                "started": 1000.0,
                "ended": 1900.0,
                "wall_s": 900.0,
                "failures": [],
                "machine": {
                    "host": "box",
                    "platform": "Linux",
                    "cpus": 2,
                    "cpu": "Xeon (family/model/stepping 6/167/1)",
                    "cpu_isa": ["avx2", "avx512f"],
                    "jax_backend": "cpu",
                    "devices": ["TFRT_CPU_0"],
                },
            }
        ],
    }
    _write_json(out / "grid.json", grid)
    for rel in rels:
        if rel in absent:
            continue
        _, env, method, seed = rel.split("/")
        d = out / rel
        # seed 0 writes the metric name of older runs (newest position), the others today's
        acc_key = "action_accuracy" if seed == "seed_0" else "action_accuracy_newest"
        _write_json(d / "config.json", {"env": env, "method": method})
        final_ret = BASE[env] + ret.get(method, 0.0)
        records = []
        for c in range(CHUNKS):
            frac = (c + 1) / CHUNKS
            rec: dict[str, Any] = {
                "step": 1000 * (c + 1),
                "chunk": c,
                "seed": int(seed.removeprefix("seed_")),
                "train/return": BASE[env] + frac * ret.get(method, 0.0),
                "eval/return": BASE[env] + frac * ret.get(method, 0.0) + noise * rng.normal(),
                "eval/return_std": 1.0,
            }
            if method in ACTIONS:
                rec[f"eval/{acc_key}"] = acc.get(method, 0.5) * frac
                if method in POSITIONS:
                    rec["train/action_accuracy_all_positions"] = 0.9 * frac
            if method in OBS:
                rec["eval/obs_mse"] = 1.0 - 0.5 * frac
            records.append(rec)
        if rel in unfinished:
            records = records[:2]
        (d / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
        if rel in unfinished:
            continue
        _write_json(d / "final.json", {"seeds": [records[-1]]})
        if rel in unevaluated:
            continue
        for partners, shift in (("train", 0.0), ("heldout", -1.0)):
            r = final_ret + shift + noise * rng.normal()
            ev: dict[str, Any] = {
                "env": env,
                "method": method,
                "partners": partners,
                "return": {"mean": r, "std": 2.0},
                "per_partner_return": {"a": r},
                "per_step": {"cum_return": list(np.linspace(0, r, EPISODE))},
            }
            if sizes:  # not from rng: the returns' noise stays the older grids'
                k = 0.1 * int(seed.removeprefix("seed_"))
                ev["obs_norm"] = 5.0 + k
                ev["z_norm"] = (11.3 if method.startswith("transam") else 1.0) + k
            if method in ACTIONS:
                a = acc.get(method, 0.5) + 0.01 * rng.normal()
                ev[acc_key] = a
                ev["per_step"][acc_key] = [*np.linspace(a - 0.2, a + 0.1, EPISODE - 1)]
                ev["per_step"][acc_key].append(None)  # no episode running
                if method in POSITIONS:
                    ev["action_accuracy_all_positions"] = min(1.0, a + 0.2)
            if method in OBS:
                ev["obs_mse"] = 0.5
                ev["per_step"]["obs_mse"] = list(np.linspace(1.0, 0.2, EPISODE))
            if method != "nam":
                p = 0.9 if method == "transam" else 0.4
                ev["probe"] = {
                    "accuracy": p + 0.01 * rng.normal(),
                    "per_step": [None, *np.linspace(0.25, p, EPISODE - 1)],
                    "chance": 0.25,
                }
                buf = io.BytesIO()
                np.savez(
                    buf,
                    coords=rng.normal(size=(40, 2)).astype(np.float32),
                    partner=np.arange(40) % 4,
                    team_names=np.asarray(["A", "B", "C", "D"]),
                    explained_variance=np.asarray([0.4, 0.2]),
                )
                (d / f"eval_{partners}_pca.npz").write_bytes(buf.getvalue())
            _write_json(d / f"eval_{partners}.json", ev)
    log = out / "log" / "tag_transam_seed_0.jsonl"
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_text(json.dumps({"event": "done", "seconds": 12.5}) + "\n{torn")


GOOD_RET = {
    "transam": 10.0,
    "oracle": 8.0,
    "liam": 5.0,
    "pel": -5.0,
    "transam-pool": 3.0,
    "transam-fuse": 9.9,
    "transam-im": 1.0,
}
GOOD_ACC = {
    "transam": 0.9,
    "liam": 0.5,
    "cail": 0.6,
    "pel": 0.55,
    "transam-fuse": 0.7,
    "transam-pool": 0.4,
    "transam-im": 0.6,
}


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any], str]:
    """A full grid (4 envs x 10 methods x 3 seeds) where TransAM is clearly the best."""
    out = tmp_path_factory.mktemp("good")
    write_grid(out, GOOD_RET, GOOD_ACC)
    path = build_report(out)
    return out, json.loads((out / "report" / "results.json").read_text()), path.read_text()


def _verdicts(results: dict[str, Any]) -> dict[str, str]:
    return {c["key"]: c["verdict"] for c in results["claims"]}


# ---------------------------------------------------------------- statistics


def test_bootstrap_of_constant_data_has_zero_width() -> None:
    mean, lo, hi = bootstrap_ci(np.full(5, 3.25))
    assert (mean, lo, hi) == pytest.approx((3.25, 3.25, 3.25), abs=1e-12)


def test_bootstrap_of_a_large_normal_sample_matches_the_normal_interval() -> None:
    x = np.random.default_rng(1).normal(5.0, 2.0, size=500)
    mean, lo, hi = bootstrap_ci(x)
    half = 1.96 * x.std(ddof=1) / np.sqrt(len(x))
    assert mean == pytest.approx(x.mean())
    assert lo == pytest.approx(x.mean() - half, abs=0.1 * half)
    assert hi == pytest.approx(x.mean() + half, abs=0.1 * half)


def test_bootstrap_agrees_with_scipy_percentile_bootstrap() -> None:
    x = np.array([1.0, 2.5, 2.0, 4.0, 3.5, 0.5, 3.0, 2.2])
    ours = bootstrap_ci(x)
    ref = scipy.stats.bootstrap(
        (x,), np.mean, method="percentile", n_resamples=10_000, rng=np.random.default_rng(7)
    ).confidence_interval
    assert ours[1] == pytest.approx(ref.low, abs=0.05)
    assert ours[2] == pytest.approx(ref.high, abs=0.05)
    assert ours[1] < x.mean() < ours[2]


def test_one_seed_interval_is_the_point_and_results_are_deterministic() -> None:
    assert interval([2.0]) == interval([2.0])
    one = interval([2.0])
    assert (one.mean, one.lo, one.hi, one.n) == (2.0, 2.0, 2.0, 1)
    assert interval([1.0, 2.0, 4.0]) == interval([1.0, 2.0, 4.0])


def test_curve_ci_uses_the_seeds_present_at_each_point() -> None:
    m = np.array([[1.0, 2.0, 3.0], [3.0, 4.0, np.nan], [5.0, 6.0, np.nan]])
    c = curve_ci(m)
    assert c["n"] == [3, 3, 1]
    assert c["mean"] == pytest.approx([3.0, 4.0, 3.0])
    assert c["lo"][2] == c["hi"][2] == 3.0  # one seed: the point
    # the vectorised columns equal one bootstrap per column
    for j in range(2):
        _, lo, hi = bootstrap_ci(m[:, j])
        assert (c["lo"][j], c["hi"][j]) == pytest.approx((float(lo), float(hi)))


def test_stratified_resampling_keeps_each_stratum_and_its_size() -> None:
    sizes = [2, 5, 3]
    idx = stratified_resample_indices(sizes, 1000, np.random.default_rng(0))
    starts = np.cumsum([0, *sizes[:-1]])
    for k, (n, start) in enumerate(zip(sizes, starts, strict=True)):
        assert idx[k].shape == (1000, n)
        assert idx[k].min() >= start and idx[k].max() < start + n
        assert len(np.unique(idx[k])) == n  # every seed of the stratum gets drawn sometimes
    with pytest.raises(ValueError, match="at least one seed"):
        stratified_resample_indices([2, 0], 10, np.random.default_rng(0))


def test_stratified_bootstrap_statistics() -> None:
    # constant strata: the mean of stratum means, exactly, whatever the sizes
    point, lo, hi = stratified_bootstrap([[1.0, 1.0], [4.0, 4.0, 4.0, 4.0]])
    assert (point, lo, hi) == pytest.approx((2.5, 2.5, 2.5), abs=1e-12)
    d = difference([5.0, 5.0], [2.0, 2.0, 2.0])
    assert (d.mean, d.lo, d.hi) == pytest.approx((3.0, 3.0, 3.0))
    # a difference's interval is wider than either side's alone
    a, b = [1.0, 2.0, 3.0, 4.0], [0.0, 0.5, 1.0, 1.5]
    d = difference(a, b)
    assert d.hi - d.lo > interval(a).hi - interval(a).lo
    assert d.mean == pytest.approx(np.mean(a) - np.mean(b))


def test_combining_verdicts() -> None:
    assert combine(["holds", "holds"], "all") == "holds"
    assert combine(["holds", "inconclusive"], "all") == "inconclusive"
    assert combine(["holds", "not run"], "all") == "inconclusive"
    assert combine(["holds", "does not hold"], "all") == "does not hold"
    assert combine(["not run", "not run"], "all") == "not run"
    assert combine([], "all") == "not run"
    assert combine(["does not hold", "holds"], "any") == "holds"
    assert combine(["does not hold", "not run"], "any") == "inconclusive"
    assert combine(["holds", "holds", "holds", "does not hold"], 3) == "holds"
    assert combine(["holds", "does not hold", "does not hold", "inconclusive"], 3) == (
        "does not hold"
    )


# ---------------------------------------------------------------- the report


def test_full_grid_writes_every_artefact(good: tuple[Path, dict[str, Any], str]) -> None:
    out, results, md = good
    report = out / "report"
    for name in ("report.md", "results.json", "marl_eval.json"):
        assert (report / name).stat().st_size > 0
    figs = sorted(p.name for p in (report / "figures").glob("*.png"))
    assert figs == sorted(
        [
            "returns_training.png",
            "action_accuracy_training.png",
            "transam_episode.png",
            "probe_per_step.png",
            "transam_pca.png",
        ]
    )
    for rel in results["figures"].values():
        assert (report / rel).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"]({rel})" in md  # embedded with a relative link
    assert results["runs"]["missing"] == [] and len(results["runs"]["finished"]) == 120
    cell = results["cells"]["spread"]["transam"]
    assert cell["seeds"] == [0, 1, 2]
    assert cell["metrics"]["return"]["mean"] == pytest.approx(-40.0, abs=0.5)
    assert cell["metrics"]["return"]["lo"] <= cell["metrics"]["return"]["mean"]
    assert cell["curves"]["return"]["step"] == [1000, 2000, 3000, 4000]
    assert cell["per_step"]["action_accuracy_newest"]["n"][-1] == 0  # the null step
    # seed 0's legacy ``action_accuracy`` is read as the newest-position accuracy
    assert cell["metrics"]["action_accuracy_newest"]["seeds"] == [0, 1, 2]
    assert cell["metrics"]["action_accuracy_all_positions"]["seeds"] == [0, 1, 2]
    assert cell["train_curves"]["action_accuracy_all_positions"]["n"] == [3, 3, 3, 3]
    assert "action_accuracy_all_positions" not in results["cells"]["spread"]["liam"]["metrics"]
    assert "action_accuracy_newest" not in results["cells"]["spread"]["nam"]["metrics"]
    assert "action_accuracy" not in results["cells"]["spread"]["transam"]["metrics"]
    # both accuracies are shown, with which one the paper's Table 1 is compared with
    assert "All window positions:" in md and "Newest position:" in md
    assert "accuracy, all positions (%)" in md and "newest position, the evaluation" in md
    # the command, budget, compute and CI method are stated
    assert "transam reproduce --budget smoke" in md and "total_steps" in md
    assert "0:15:00" in md and "percentile bootstrap" in md and "10,000" in md
    assert "Xeon (family/model/stepping 6/167/1); ISA avx2 avx512f" in md  # the CPU, named
    assert "rliable" in md and "crude" in md
    # marl-eval's raw data layout
    me = json.loads((report / "marl_eval.json").read_text())
    run = me["mpe"]["simple_spread"]["transam"]["run_0"]
    assert run["step_0"] == {
        "step_count": 1000,
        "return": [pytest.approx(-47.5, abs=1)],
        "action_accuracy_newest": [pytest.approx(0.225)],  # seed 0: a legacy name
    }
    assert set(run["absolute_metrics"]) == {
        "return",
        "action_accuracy_newest",
        "action_accuracy_all_positions",
        "heldout_return",
    }


def test_claims_hold_when_transam_is_clearly_better(
    good: tuple[Path, dict[str, Any], str],
) -> None:
    _, results, md = good
    v = _verdicts(results)
    for key in (
        "returns-vs-oracle",
        "returns-highest",
        "accuracy-cooperative",
        "accuracy-overall",
        "ablation-pool",
        "ablation-fuse",
        "episode-evolution",
        "probe-above-chance",
        "probe-above-baselines",
        "liam-above-pel-cail",
    ):
        assert v[key] == "holds", key
    assert v["pel-accuracy"] == "does not hold"  # PEL 0.55 vs TransAM 0.9 everywhere
    assert v["accuracy-mixed-under"] == "does not hold"
    assert v["ablation-im"] == "holds"
    assert v["pel-lowest-return"] == "holds"
    assert "## Paper claims" in md
    for c in results["claims"]:
        assert f"`{c['key']}`: {c['verdict']}" in md


def test_claims_fail_when_transam_is_worse(tmp_path: Path) -> None:
    ret = {**GOOD_RET, "transam": -10.0}
    acc = {**GOOD_ACC, "transam": 0.3}
    write_grid(tmp_path, ret, acc, methods=("transam", "oracle", "liam", "pel"), seeds=(0, 1))
    results = json.loads(build_report(tmp_path, draw=False).with_name("results.json").read_text())
    v = _verdicts(results)
    assert results["figures"] == {} and not list((tmp_path / "report").glob("figures/*.png"))
    assert v["returns-vs-oracle"] == "does not hold"
    assert v["returns-highest"] == "does not hold"
    assert v["accuracy-overall"] == "does not hold"
    assert v["ablation-pool"] == "not run"  # no ablation in this grid
    check = results["claims"][0]["per_env"]["spread"]["checks"][0]
    assert check["diff"] < 0 and check["ci"][1] < 0 and check["n_a"] == 2
    # the runs' seeds (--seeds 0 1), not the budget's default count (3), say how it was run
    md = (tmp_path / "report" / "report.md").read_text()
    assert results["grid"]["seeds"] == [0, 1]
    assert "| seeds | 0, 1 |" in md and "| seeds | 3 |" not in md


def test_tied_methods_are_inconclusive_and_one_seed_never_decides(tmp_path: Path) -> None:
    tie = {"transam": 10.0, "oracle": 10.0}
    write_grid(tmp_path / "tie", tie, {}, envs=("spread",), methods=("transam", "oracle"))
    results = json.loads(
        build_report(tmp_path / "tie", draw=False).with_name("results.json").read_text()
    )
    claim = results["claims"][0]
    assert claim["key"] == "returns-vs-oracle"
    assert claim["per_env"]["spread"]["verdict"] == "holds"  # matches, within the margin
    assert claim["verdict"] == "inconclusive" and "not run in tag" in claim["note"]
    write_grid(
        tmp_path / "one",
        {"transam": 50.0},
        {},
        envs=("spread",),
        methods=("transam", "oracle"),
        seeds=(0,),
    )
    results = json.loads(
        build_report(tmp_path / "one", draw=False).with_name("results.json").read_text()
    )
    check = results["claims"][0]["per_env"]["spread"]["checks"][0]
    assert check["verdict"] == "inconclusive" and "seeds" in check["reason"]
    assert results["cells"]["spread"]["transam"]["metrics"]["return"]["n"] == 1


def test_partial_grid_reports_what_exists_and_lists_what_is_missing(tmp_path: Path) -> None:
    write_grid(
        tmp_path,
        GOOD_RET,
        GOOD_ACC,
        envs=("spread",),
        methods=("transam", "nam", "transam-pool"),
        seeds=(0, 1),
        absent={"runs/spread/transam-pool/seed_1"},
        unfinished={"runs/spread/transam/seed_1"},
        unevaluated={"runs/spread/nam/seed_1"},
        sizes=False,
    )
    (tmp_path / "runs/spread/nam/seed_0/eval_heldout.json").write_text("{torn")
    grid = json.loads((tmp_path / "grid.json").read_text())  # one run failed, one failed then
    grid["invocations"][0]["failures"] = [  # finished on a later invocation
        "runs/spread/transam/seed_1: RuntimeError: boom",
        "runs/spread/nam/seed_0: BrokenProcessPool: gone",
    ]
    (tmp_path / "grid.json").write_text(json.dumps(grid))
    md = build_report(tmp_path).read_text()
    results = json.loads((tmp_path / "report" / "results.json").read_text())
    assert results["compute"]["failures"] == ["runs/spread/transam/seed_1: RuntimeError: boom"]
    assert results["compute"]["failures_of_finished_runs"] == 1
    assert "RuntimeError: boom" in md and "BrokenProcessPool" not in md
    runs = results["runs"]
    assert runs["missing"] == ["runs/spread/transam-pool/seed_1"]
    assert runs["unfinished"] == ["runs/spread/transam/seed_1"]
    assert runs["not_evaluated_train"] == ["runs/spread/nam/seed_1"]
    assert "eval_heldout.json: unreadable" in runs["problems"]["runs/spread/nam/seed_0"][0]
    for rel in ("runs/spread/transam-pool/seed_1", "runs/spread/transam/seed_1"):
        assert f"`{rel}`" in md
    cells = results["cells"]["spread"]
    assert cells["transam"]["seeds"] == [0] and cells["transam"]["seeds_unfinished"] == [1]
    assert cells["transam"]["curves"]["return"]["n"] == [2, 2, 1, 1]  # the unfinished seed
    nam = cells["nam"]["metrics"]["return"]
    assert nam["source"] == "mixed" and nam["n"] == 2  # seed 1 from final.json
    assert "†" in md and "not run" in md
    assert "action_accuracy_newest" not in cells["nam"]["metrics"]
    assert "Sizes of the policy's inputs" not in md  # evaluations older than the record
    v = _verdicts(results)
    assert v["returns-highest"] == "inconclusive"  # TransAM has one finished seed
    assert v["accuracy-mixed-under"] == "not run"  # no LBF
    assert v["ablation-pool"] == "inconclusive"  # one seed on each side
    assert v["returns-vs-oracle"] == "not run"  # no Oracle


def _spread_levels(monkeypatch: pytest.MonkeyPatch, by_step: list[float | None]) -> None:
    """Spread's shipped manifest replaced by one recording ``by_step`` as its per-step level."""
    from transam.partners import learned

    found = {
        "action_ceiling": 1.0,
        "memoryless_accuracy": 0.5,
        "majority_rate": 0.2,
        "memoryless_own_accuracy": 0.4,
        "memoryless_own_accuracy_by_step": by_step,
        "population_digest": "abc",
    }

    def load(env: str, root: object = None) -> dict:
        if env != "spread":
            raise FileNotFoundError(env)
        return {"default": {"diversity": found}}

    monkeypatch.setattr(learned, "load_manifest", load)


@pytest.mark.parametrize(
    ("level", "verdict"),
    [
        (np.linspace(0.9, 0.2, EPISODE), "holds"),  # the level falls: the gain grows
        (np.linspace(0.0, 0.9, EPISODE), "does not hold"),  # it rises faster than accuracy
    ],
)
def test_accuracy_gain_is_read_over_the_per_step_memoryless_level(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, level: np.ndarray, verdict: str
) -> None:
    _spread_levels(monkeypatch, [*level[:-1].tolist(), None])
    write_grid(tmp_path, GOOD_RET, GOOD_ACC, envs=("spread",), methods=("transam",))
    build_report(tmp_path, draw=True)
    results = json.loads((tmp_path / "report" / "results.json").read_text())
    claims = {c["key"]: c for c in results["claims"]}
    # the raw accuracy rises by 0.3 from the first to the last valued step either way
    assert claims["episode-evolution"]["per_env"]["spread"]["verdict"] == "holds"
    gain = results["cells"]["spread"]["transam"]["metrics"]["trend:accuracy_gain"]
    assert gain["mean"] == pytest.approx(0.3 - (level[-2] - level[0]), abs=0.05)
    assert claims["episode-evolution-gain"]["per_env"]["spread"]["verdict"] == verdict
    assert results["partner_levels"]["spread"]["memoryless_own_accuracy_by_step"][0] == level[0]
    assert (tmp_path / "report" / "figures" / "transam_episode.png").exists()


def test_levels_follow_the_grids_partners(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The per-step level of the default population is not applied to other partners."""
    _spread_levels(monkeypatch, [0.5] * EPISODE)
    write_grid(tmp_path, GOOD_RET, GOOD_ACC, envs=("spread",), methods=("transam",))
    grid = json.loads((tmp_path / "grid.json").read_text())
    (tmp_path / "grid.json").write_text(json.dumps({**grid, "partners": "heuristic"}))
    results = json.loads(build_report(tmp_path, draw=False).with_name("results.json").read_text())
    assert results["partner_levels"] == {"spread": None}
    assert "trend:accuracy_gain" not in results["cells"]["spread"]["transam"]["metrics"]
    gain = {c["key"]: c for c in results["claims"]}["episode-evolution-gain"]
    assert gain["per_env"]["spread"]["verdict"] == "not run"


def test_report_tables_match_results_json(good: tuple[Path, dict[str, Any], str]) -> None:
    _, results, md = good
    usual = results["usual_seeds"]
    checked = 0
    for section, metric in (
        ("### Final return", "return"),
        ("### Action reconstruction", "action_accuracy_newest"),
        ("### Observation reconstruction", "obs_mse"),
        ("### Partner-identity probe", "probe_accuracy"),
        ("### Sizes of the policy's inputs", "z_norm"),
    ):
        body = md.split(section, 1)[1].split("\n### ", 1)[0]
        header = next(ln for ln in body.splitlines() if ln.startswith("| method |"))
        envs = [c.strip() for c in header.strip("|").split("|")][1:]
        for method in PAPER_METHODS:
            row = next(
                (ln for ln in body.splitlines() if ln.startswith(f"| **{display(method)}** |")),
                None,
            )
            if row is None:
                continue
            cells = [c.strip() for c in row.strip("|").split("|")][1:]
            for env, text in zip(envs, cells, strict=True):
                s = results["cells"][env][method]["metrics"][metric]
                assert text == fmt_stat(metric, s, usual), (env, method, metric)
                checked += 1
    assert checked == 4 * (10 + 7 + 4 + 9 + 10)
    # the ablation table has the four variants' returns
    ablation = md.split("### Spread ablation", 1)[1].split("\n### ", 1)[0]
    for m in ("transam", "transam-pool", "transam-fuse", "transam-im"):
        s = results["cells"]["spread"][m]["metrics"]["return"]
        assert fmt_stat("return", s, results["usual_seeds"]) in ablation


def test_pca_file_is_read_and_bad_files_are_tolerated(tmp_path: Path) -> None:
    path = tmp_path / "p.npz"
    np.savez(path, coords=np.ones((6, 2)), partner=np.arange(6) % 3)
    proj = read_pca(path)
    assert proj is not None and proj.coords.shape == (6, 2) and proj.team_names is None
    np.savez(path, something=np.ones(3))
    assert read_pca(path) is None
    path.write_bytes(b"not a zip")
    assert read_pca(path) is None


def test_cli_prints_a_summary(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_grid(tmp_path, GOOD_RET, GOOD_ACC, envs=("lbf",), methods=("transam", "nam"))
    Report(tmp_path).run()
    text = "".join(capsys.readouterr().out.split())  # rich wraps long paths mid-word
    assert "report.md" in text and "6finished" in text and "claimsnotrun:" in text
    assert re.search(r"lbf│transam│3│10\.\d\d\[", text)  # summary table


def test_a_directory_without_a_grid_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="holds no grid"):
        build_report(tmp_path)
