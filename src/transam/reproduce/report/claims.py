"""The paper's main claims as checks on the aggregated results, each with a computed verdict.

A claim is a list of *checks* (one comparison of two methods, or of a method with a constant,
on one metric) evaluated in each of its environments. A check compares per-seed values with a
95% percentile-bootstrap CI of the difference of means (the seeds of each side resampled
independently, i.e. a two-stratum bootstrap):

* ``better``: A is better than B (higher, or lower for an error): *holds* when the whole CI is
  on A's side of 0, *does not hold* when it is wholly on B's side, else *inconclusive*.
* ``not_worse``: A matches or exceeds B: *holds* when the CI's worst end is within the margin
  of B, *does not hold* when even its best end is worse than B by more than the margin.
* ``similar``: the CI lies within +-margin (holds) or wholly outside it (does not hold).

The margin is 5% of the span of the environment's scores for that metric (the methods' final
means and their first evaluations during training), so "matches" means "within a small
fraction of what training changes".

A check needs at least 2 seeds on each side (with 1 seed there is no spread: inconclusive); a
method with no finished run is *not run*; a method that ran but does not produce the metric
(NAM has no action decoder) is *not applicable* and the check is dropped. Checks combine
within an environment and then across environments by the claim's rule ("all", "any", or "at
least k environments").

Accuracy claims use ``action_accuracy_newest`` (the prediction at the newest window position,
what execution decodes): every method with an action decoder has it, so methods compare on
equal terms. The all-positions accuracy exists only for methods that decode every window
position and is inflated by the window's look-ahead; the report shows it, no claim uses it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

from transam.registry import PAPER_ENVS, PAPER_METHODS, methods_of
from transam.reproduce.report.stats import difference, interval

Relation = Literal["better", "not_worse", "similar"]
Verdict = Literal["holds", "does not hold", "inconclusive", "not run"]
VERDICTS: tuple[str, ...] = ("holds", "does not hold", "inconclusive", "not run")
MARGIN_FRACTION = 0.05
MIN_SEEDS = 2

HIGHER_IS_BETTER = {
    "return": True,
    "heldout_return": True,
    "action_accuracy_newest": True,
    "action_accuracy_all_positions": True,
    "obs_mse": False,
    "probe_accuracy": True,
    "trend:action_accuracy_newest": True,
    "trend:accuracy_gain": True,
    "trend:obs_mse": False,
}
METRIC_LABEL = {
    "return": "return",
    "heldout_return": "held-out return",
    "action_accuracy_newest": "action accuracy (newest position)",
    "action_accuracy_all_positions": "action accuracy (all window positions)",
    "obs_mse": "obs. MSE",
    "probe_accuracy": "probe accuracy",
    "trend:action_accuracy_newest": "action accuracy (newest), late - early in the episode",
    "trend:accuracy_gain": "action accuracy (newest) above the per-step memoryless level, "
    "late - early in the episode",
    "trend:obs_mse": "obs. MSE, late - early in the episode",
}
BASELINES = methods_of("baseline")
"""The non-Oracle baselines of the paper."""
ALL_ENVS = PAPER_ENVS
NOT_ABLATIONS = tuple(m for m in PAPER_METHODS if m not in methods_of("ablation"))
"""TransAM, the Oracle and the baselines, in the paper's order (Figure 3's methods)."""


@dataclass(frozen=True)
class Check:
    metric: str
    a: str
    b: str | None = None
    """another method, or None to compare with ``const``"""
    relation: Relation = "better"
    const: float | Literal["chance"] = 0.0
    """the constant B when ``b`` is None ("chance": the probe's chance level)"""

    def describe(self) -> str:
        better = ">" if HIGHER_IS_BETTER[self.metric] else "<"
        op = {"better": better, "not_worse": f"{better}=", "similar": "≈"}[self.relation]
        other = self.b if self.b is not None else str(self.const)
        return f"{self.a} {op} {other} ({METRIC_LABEL[self.metric]})"


@dataclass(frozen=True)
class Claim:
    key: str
    text: str
    """the paper's words (quoted or closely paraphrased)"""
    where: str
    """where the paper says it"""
    envs: tuple[str, ...]
    checks: tuple[Check, ...]
    within: Literal["all", "any"] = "all"
    """how the checks of one environment combine"""
    across: int | None = None
    """environments that must hold (None: all of ``envs``)"""


def _vs(metric: str, a: str, others: Sequence[str], relation: Relation = "better") -> tuple:
    return tuple(Check(metric, a, b, relation) for b in others)


def _beats(metric: str, winners: Sequence[str], loser: str) -> tuple:
    return tuple(Check(metric, w, loser) for w in winners)


CLAIMS: tuple[Claim, ...] = (
    Claim(
        "returns-vs-oracle",
        "“TransAM matches or exceeds Oracle across all environments.”",
        "§5.3.1 Task Returns (Fig. 3)",
        ALL_ENVS,
        (Check("return", "transam", "oracle", "not_worse"),),
    ),
    Claim(
        "returns-highest",
        "TransAM achieves the highest returns: “leads to higher episodic returns” (Abstract), "
        "“achieves superior episodic returns” (§1), “achieving the highest returns” (§5.3.2); "
        "checked against every non-Oracle baseline.",
        "Abstract; §1; §5.3.2 (Fig. 3)",
        ALL_ENVS,
        _vs("return", "transam", BASELINES),
    ),
    Claim(
        "oracle-upper-bound",
        "“Oracle defines the upper performance bound” (checked against the non-Oracle "
        "baselines; TransAM is the previous claim).",
        "§5.3.1 Task Returns (Fig. 3)",
        ALL_ENVS,
        _vs("return", "oracle", BASELINES, "not_worse"),
    ),
    Claim(
        "pel-lowest-return",
        "“PEL yields the lowest returns in most environments.”",
        "§5.3.1 Task Returns (Fig. 3)",
        ALL_ENVS,
        _beats("return", tuple(m for m in NOT_ABLATIONS if m != "pel"), "pel"),
        across=3,
    ),
    Claim(
        "liam-above-pel-cail",
        "LIAM “lags behind other baselines in agent modeling but achieves significantly higher "
        "returns than PEL and CAIL.” (returns part)",
        "§5.3.2 Agent Modeling",
        ALL_ENVS,
        _vs("return", "liam", ("pel", "cail")),
    ),
    Claim(
        "accuracy-overall",
        "“Our results demonstrate that the proposed method outperforms baseline approaches in "
        "agent modeling accuracy” (every baseline that reconstructs actions, every env).",
        "§1 Introduction; Abstract",
        ALL_ENVS,
        _vs("action_accuracy_newest", "transam", BASELINES),
    ),
    Claim(
        "accuracy-cooperative",
        "TransAM's action reconstruction is “outperforming all baselines in the two "
        "cooperative tasks” (Spread, Overcooked).",
        "§5.3.2 Agent Modeling (Fig. 4)",
        ("spread", "overcooked"),
        _vs("action_accuracy_newest", "transam", BASELINES),
    ),
    Claim(
        "accuracy-mixed-under",
        "TransAM's action reconstruction is “underperforming in the mixed setting” (LBF): some "
        "baseline is more accurate.",
        "§5.3.2 Agent Modeling (Fig. 4)",
        ("lbf",),
        _beats("action_accuracy_newest", BASELINES, "transam"),
        within="any",
    ),
    Claim(
        "pel-accuracy",
        "“PEL matches or surpasses TransAM in three of four tasks” (action accuracy).",
        "§5.3.2 Agent Modeling (Fig. 4)",
        ALL_ENVS,
        (Check("action_accuracy_newest", "pel", "transam", "not_worse"),),
        across=3,
    ),
    Claim(
        "episode-evolution",
        "“As the episode progresses, the embeddings become more informative, improving agent "
        "modeling accuracy”: TransAM's action accuracy rises and its observation MSE falls "
        "from the first to the last quarter of the episode.",
        "§5.3.3 Model Evaluation (Fig. 5)",
        ALL_ENVS,
        (
            Check("trend:action_accuracy_newest", "transam", None, "better", 0.0),
            Check("trend:obs_mse", "transam", None, "better", 0.0),
        ),
    ),
    Claim(
        "episode-evolution-gain",
        "“The embeddings become more informative” as the episode progresses, read as: "
        "TransAM's action accuracy above what a predictor without history reaches at the same "
        "timestep (the population's per-step memoryless level from the controlled agent's view, "
        "recorded with its manifest) grows from the first to the last quarter of the episode "
        "(this reproduction's reading: the level itself changes within the episode).",
        "§5.3.3 Model Evaluation (operationalised here)",
        ALL_ENVS,
        (Check("trend:accuracy_gain", "transam", None, "better", 0.0),),
    ),
    Claim(
        "ablation-fuse",
        "TransAM-fuse “achieves comparable returns; yet suffers in agent modeling tasks”.",
        "§5.4 Ablation (Table 1)",
        ("spread",),
        (
            Check("return", "transam-fuse", "transam", "similar"),
            Check("action_accuracy_newest", "transam", "transam-fuse"),
        ),
    ),
    Claim(
        "ablation-pool",
        "TransAM-pool “leads to poor performance for both episodic returns and action "
        "reconstruction accuracy”.",
        "§5.4 Ablation (Table 1)",
        ("spread",),
        (
            Check("return", "transam", "transam-pool"),
            Check("action_accuracy_newest", "transam", "transam-pool"),
        ),
    ),
    Claim(
        "ablation-im",
        "TransAM-im “produces the worst returns and second-lowest modeling accuracy”.",
        "§5.4 Ablation (Table 1)",
        ("spread",),
        (
            *_beats("return", ("transam", "transam-pool", "transam-fuse"), "transam-im"),
            Check("action_accuracy_newest", "transam", "transam-im"),
            Check("action_accuracy_newest", "transam-fuse", "transam-im"),
            Check("action_accuracy_newest", "transam-im", "transam-pool"),
        ),
    ),
    Claim(
        "probe-above-chance",
        "“Our approach generates strong policy representations” (Abstract), read as: a linear "
        "probe recovers the partner team from TransAM's embedding above chance (the probe is "
        "this reproduction's test, not the paper's).",
        "Abstract; §1 (operationalised here)",
        ALL_ENVS,
        (Check("probe_accuracy", "transam", None, "better", "chance"),),
    ),
    Claim(
        "probe-above-baselines",
        "“Provides robust agent policy representation” (§1), read as: the partner team is "
        "better recovered from TransAM's embedding than from each baseline's (probe accuracy; "
        "this reproduction's test).",
        "§1 (operationalised here)",
        ALL_ENVS,
        _vs("probe_accuracy", "transam", BASELINES),
    ),
)

NOT_CHECKED = (
    "“In the overcooked environment, TransAM converges the fastest, aligning with its highest "
    "reward margin over the baselines” (§5.3.3): needs a convergence-speed measure the paper "
    "does not define.",
    "“CAIL underperforms in predator-prey and level-based foraging but excels in cooperative "
    "navigation and Overcooked”, “CARL performs moderately overall”, “NAM achieves moderate to "
    "low returns” (§5.3.1): qualitative; the per-env return table shows them.",
)


# ---------------------------------------------------------------- evaluation


def combine(verdicts: Sequence[str], rule: Literal["all", "any"] | int) -> Verdict:
    """Combine verdicts: "all" (every one holds), "any", or an int k (at least k hold)."""
    if not verdicts or all(v == "not run" for v in verdicts):
        return "not run"
    holds = sum(v == "holds" for v in verdicts)
    fails = sum(v == "does not hold" for v in verdicts)
    if rule == "any":
        if holds:
            return "holds"
        return "does not hold" if fails == len(verdicts) else "inconclusive"
    need = len(verdicts) if rule == "all" else rule
    if holds >= need:
        return "holds"
    if len(verdicts) - fails < need:
        return "does not hold"
    return "inconclusive"


def _scale(cells: dict[str, Any], metric: str) -> float:
    """The span of an environment's scores for ``metric``: lowest to highest of the methods'
    final means and of their first evaluations during training (a near-untrained reference,
    so that two close methods alone do not shrink the scale to their own difference); the
    probe's chance level is a reference point for the probe."""
    curve_key = "return" if metric == "heldout_return" else metric
    points = []
    for c in cells.values():
        if metric in c.get("metrics", {}):
            points.append(c["metrics"][metric]["mean"])
        first = (c.get("curves", {}).get(curve_key) or {}).get("mean") or [None]
        if first[0] is not None:
            points.append(first[0])
        if metric == "probe_accuracy" and c.get("probe_chance") is not None:
            points.append(c["probe_chance"])
    return float(max(points) - min(points)) if len(points) > 1 else 0.0


def _side(cells: dict[str, Any], method: str, metric: str) -> tuple[list[float] | None, str]:
    """The per-seed values of one side, or None with why ("not run" / "n/a")."""
    cell = cells.get(method)
    if cell is None or not cell.get("seeds"):
        return None, "not run"
    stat = cell.get("metrics", {}).get(metric)
    if stat is None:
        return None, "n/a"
    return list(stat["values"]), ""


def evaluate_check(check: Check, cells: dict[str, Any]) -> dict[str, Any] | None:
    """One check in one environment (``cells``: method -> aggregated cell); None when it does
    not apply (a method that ran but lacks the metric)."""
    row: dict[str, Any] = {"check": check.describe(), "metric": check.metric}
    a, why_a = _side(cells, check.a, check.metric)
    if check.b is not None:
        b, why_b = _side(cells, check.b, check.metric)
    else:
        const = check.const
        if const == "chance":
            chance = (cells.get(check.a) or {}).get("probe_chance")
            b, why_b = ([float(chance)], "") if chance is not None else (None, "n/a")
        else:
            b, why_b = [float(const)], ""
    if "n/a" in (why_a, why_b):
        return None if "not run" not in (why_a, why_b) else {**row, "verdict": "not run"}
    if a is None or b is None:
        return {**row, "verdict": "not run"}
    sign = 1.0 if HIGHER_IS_BETTER[check.metric] else -1.0
    diff = difference(a, b)
    lo, hi = sorted((sign * diff.lo, sign * diff.hi))
    margin = 0.0 if check.relation == "better" else MARGIN_FRACTION * _scale(cells, check.metric)
    row.update(
        a_mean=interval(a).mean,
        b_mean=interval(b).mean,
        diff=sign * diff.mean,
        ci=[lo, hi],
        margin=None if check.relation == "better" else margin,
        n_a=len(a),
        n_b=len(b) if check.b is not None else None,
    )
    if len(a) < MIN_SEEDS or (check.b is not None and len(b) < MIN_SEEDS):
        return {**row, "verdict": "inconclusive", "reason": f"fewer than {MIN_SEEDS} seeds"}
    verdict: Verdict = "inconclusive"
    if check.relation == "better":
        verdict = "holds" if lo > 0 else "does not hold" if hi < 0 else "inconclusive"
    elif check.relation == "not_worse":
        verdict = "holds" if lo >= -margin else "does not hold" if hi < -margin else "inconclusive"
    elif -margin <= lo and hi <= margin:
        verdict = "holds"
    elif lo > margin or hi < -margin:
        verdict = "does not hold"
    return {**row, "verdict": verdict}


def evaluate_claims(cells: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Every claim's verdict, per environment and overall, with the numbers behind it
    (``cells``: env -> method -> aggregated cell, see :func:`~.aggregate.cells`)."""
    results = []
    for claim in CLAIMS:
        per_env: dict[str, Any] = {}
        for env in claim.envs:
            env_cells = cells.get(env, {})
            rows = [r for r in (evaluate_check(c, env_cells) for c in claim.checks) if r]
            per_env[env] = {
                "verdict": combine([r["verdict"] for r in rows], claim.within),
                "checks": rows,
            }
        env_verdicts = [per_env[e]["verdict"] for e in claim.envs]
        rule: Literal["all"] | int = "all" if claim.across is None else claim.across
        verdict = combine(env_verdicts, rule)
        run = [e for e in claim.envs if per_env[e]["verdict"] != "not run"]
        note = ""
        if run and len(run) < len(claim.envs):
            missing = [e for e in claim.envs if e not in run]
            note = f"not run in {', '.join(missing)}"
        results.append(
            {
                "key": claim.key,
                "claim": claim.text,
                "where": claim.where,
                "envs": list(claim.envs),
                "rule": f"{claim.within} checks per env; "
                + ("all envs" if claim.across is None else f"at least {claim.across} envs"),
                "verdict": verdict,
                "note": note,
                "per_env": per_env,
            }
        )
    return results
