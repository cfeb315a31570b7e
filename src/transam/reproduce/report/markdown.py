"""report.md: the results of a grid (:mod:`~transam.reproduce.report.results`) as markdown
tables, figures and the paper's claims with their computed verdicts. Only formatting: every
number comes from results.json.
"""

from __future__ import annotations

import json
from typing import Any

from transam.registry import display
from transam.reproduce.report import claims
from transam.reproduce.report.aggregate import ACC_ALL, ACC_NEWEST, SOURCE_EVAL
from transam.reproduce.report.load import METHOD_ORDER
from transam.reproduce.report.results import CI_METHOD, FIGURES, Table

METRIC_TITLE = {
    "return": "return",
    "heldout_return": "return",
    ACC_NEWEST: "action accuracy, newest position (%)",
    ACC_ALL: "action accuracy, all window positions (%)",
    "probe_accuracy": "probe accuracy (%)",
    "obs_mse": "observation MSE",
    "z_norm": "embedding size |z_scale · z_t| in the policy's input",
    "obs_norm": "observation size |o_t|",
}
PERCENT = (ACC_NEWEST, ACC_ALL, "probe_accuracy", f"trend:{ACC_NEWEST}", "trend:accuracy_gain")
ACCURACY_NOTE = (
    "Two accuracies. *Newest position*: the decoder on the embedding the policy acted on, "
    "against the partners' actual actions at that step (the authors' code logs this one in "
    "evaluation); every method with an action decoder has it, and the claims use it. *All "
    "window positions*: the mean over every valid position of every window (the authors' "
    "code logs this one in training); only methods that decode each window position have it "
    "(TransAM, -fuse, -im; absent, not equal to the newest, for LIAM, CAIL, PEL and "
    "TransAM-pool, which decode one embedding per step). TransAM's window is bidirectional, "
    "so at an older position the later observations in the window reveal the partners' "
    "action (it is read off their next velocity): the all-positions number is inflated by "
    "that look-ahead and is not what execution can use. The paper does not say which of the "
    "two its tables report. Its Table 1 (85.72% for TransAM on Spread) is compared here with "
    "the newest position, the evaluation metric of the authors' code and the only one "
    "comparable across methods; if the paper's number is the all-positions one, compare it "
    "with the all-positions column instead (shared/spec/fidelity.md: a newest-position "
    "accuracy of about 64% gives about 86% over all positions). Observation MSE likewise: "
    "`obs_mse` is the newest position's."
)


# ---------------------------------------------------------------- formatting


def fmt_value(metric: str, x: float | None) -> str:
    if x is None:
        return "—"
    if metric in PERCENT:
        return f"{100 * x:.1f}"
    if "mse" in metric:
        return f"{x:.4g}"
    return f"{x:.2f}"


def fmt_stat(metric: str, s: dict[str, Any], usual_n: int | None = None) -> str:
    """``mean ± std [lo, hi]`` (std across seeds), plus ``(n=K)`` where K is not the usual
    number of seeds or is 1, and † for a last-training-eval value. The single formatter of
    every table cell (the tests compare it with results.json)."""
    f = lambda x: fmt_value(metric, x)
    text = f"{f(s['mean'])} ± {f(s['std'])} [{f(s['lo'])}, {f(s['hi'])}]"
    if s["n"] != usual_n or s["n"] == 1:
        text += f" (n={s['n']})"
    if s.get("source", SOURCE_EVAL) != SOURCE_EVAL:
        text += " †"
    return text


def _cell_text(table: Table, env: str, method: str, metric: str, usual_n: int | None) -> str:
    c = table.get(env, {}).get(method)
    if c is None or not c["seeds"]:
        return "not run"
    s = c["metrics"].get(metric)
    return "—" if s is None else fmt_stat(metric, s, usual_n)


def _md_table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return lines + ["| " + " | ".join(r) + " |" for r in rows]


def metric_table(
    table: Table, metric: str, usual_n: int | None, methods: list[str] | None = None
) -> list[str]:
    """Methods x environments for one final metric (only rows/columns with some value)."""
    envs = [e for e in table if any(metric in c["metrics"] for c in table[e].values())]
    if methods is None:
        methods = _methods_with(table, metric)
    if not envs or not methods:
        return ["_No run has this metric yet._"]
    rows = [
        [f"**{display(m)}**", *(_cell_text(table, e, m, metric, usual_n) for e in envs)]
        for m in methods
    ]
    return _md_table(["method", *envs], rows)


def _methods_with(table: Table, metric: str) -> list[str]:
    seen: list[str] = []
    for env in table.values():
        for m, c in env.items():
            if metric in c["metrics"] and m not in seen:
                seen.append(m)
    order = METHOD_ORDER
    return sorted(seen, key=lambda m: (order.index(m) if m in order else len(order), m))


def _episode_std_table(table: Table) -> list[str]:
    envs = [e for e in table if any(c["episode_return_std"] is not None for c in table[e].values())]
    methods = _methods_with(table, "return")
    if not envs:
        return ["_No evaluation yet._"]
    rows = []
    for m in methods:
        row = [f"**{display(m)}**"]
        for e in envs:
            std = table[e].get(m, {}).get("episode_return_std")
            row.append("—" if std is None else f"{std:.2f}")
        rows.append(row)
    return _md_table(["method", *envs], rows)


# ---------------------------------------------------------------- partner levels


def _levels_md(table: Table, levels: dict[str, dict[str, Any] | None]) -> list[str]:
    """Each method's newest-position accuracy beside its env's partner levels."""
    envs = [e for e in table if any(ACC_NEWEST in c["metrics"] for c in table[e].values())]
    if not envs:
        return []
    pct = lambda x: f"{100 * x:.1f}"
    rows = []
    for key, label in (
        ("action_ceiling", "ceiling E[max π(a|o)]"),
        ("memoryless_accuracy", "memoryless, team-agnostic"),
        ("memoryless_own_accuracy", "memoryless, controlled agent's view"),
        ("memoryless_own2_accuracy", "the same from two steps (partners' velocities)"),
        ("memoryless_window_accuracy", "the same from TransAM's window (five steps)"),
        ("majority_rate", "majority action"),
    ):
        cells = [
            pct(lv[key]) if (lv := levels.get(e)) and lv.get(key) is not None else "not recorded"
            for e in envs
        ]
        rows.append([f"*{label}*", *cells])
    for m in _methods_with(table, ACC_NEWEST):
        cells = []
        for e in envs:
            s = table[e].get(m, {}).get("metrics", {}).get(ACC_NEWEST)
            cells.append(pct(s["mean"]) if s else "—")
        rows.append([f"**{display(m)}** (newest)", *cells])
    digests = ", ".join(
        f"{e} {lv['population_digest']}" for e in envs if (lv := levels.get(e)) is not None
    )
    return [
        "Newest-position accuracy (%, mean over seeds) beside the partners' own levels, from "
        "`transam partners diversity ENV --record` (the population the grid trained against): "
        "the *ceiling* is the "
        "partners' mean most-likely-action probability under their own observations (no "
        "predictor can expect more); the *memoryless* level is an MLP's held-out accuracy at "
        "predicting a partner's action from that partner's current observation alone, pooled "
        "over all teams (no team, no history), and the same from the controlled agent's current "
        "observation (what an agent model has at one step without its history), and from its "
        "current and previous observations (the partners' velocities readable), and from the "
        "last five (what TransAM's window holds); *majority* is the most frequent action's "
        "rate. The levels are fits, so lower bounds (a level below a shorter view's is a fit "
        "short of its data, not less information). "
        "A model at the memoryless levels has learned nothing about whom it plays with: above "
        "the one-step level but not the two-step one, it may have learned only the state."
        + (f" Measured on population digests: {digests}." if digests else ""),
        "",
        *_md_table(["", *envs], rows),
    ]


# ---------------------------------------------------------------- sections


def _input_sizes_md(table: Table, usual_n: int | None) -> list[str]:
    """|z_scale * z_t| and |o_t|, the policy's two inputs (final evaluation), where recorded:
    an embedding far larger than the observation drowns it in the policy's first layer."""
    if not _methods_with(table, "z_norm"):
        return []  # evaluations older than the record
    return [
        "### Sizes of the policy's inputs",
        "",
        "Mean Euclidean size over the episodes' steps of the embedding as the policy reads it, "
        "|z_scale · z_t| (NAM's z is its previous action, one-hot), and of the observation "
        "|o_t|; the policy's input is their concatenation.",
        "",
        "Embedding, |z_scale · z_t|:",
        "",
        *metric_table(table, "z_norm", usual_n),
        "",
        "Observation, |o_t|:",
        "",
        *metric_table(table, "obs_norm", usual_n),
        "",
    ]


def _hms(seconds: float) -> str:
    s = round(seconds)
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _claims_md(results: list[dict[str, Any]]) -> list[str]:
    lines = [
        "Each claim is checked per environment on the final evaluation (training partners), "
        "with the bootstrap CI of the difference of means (signed so that > 0 favours the "
        "claim's first method): **better** holds when the whole CI is > 0 and does not hold "
        "when it is wholly < 0; **matches or exceeds** (`>=`) holds when the CI's low end is "
        f"above -margin and does not hold when its high end is below -margin; **similar** (≈) "
        f"holds when the CI lies within ±margin. The margin is {claims.MARGIN_FRACTION:.0%} of "
        "the span of that environment's scores for that metric: from the lowest to the highest "
        "of the methods' final means and their first evaluations during training (a "
        "near-untrained reference). A check with "
        f"fewer than {claims.MIN_SEEDS} seeds on a side is inconclusive; a method not run "
        "makes it *not run*; a method without the metric (no decoder) drops the check. "
        "Verdicts below are computed from results.json, not written by hand.",
        "",
        *_md_table(
            ["#", "claim", "where", "verdict"],
            [
                [str(i + 1), f"`{c['key']}`", c["where"], f"**{c['verdict']}**"]
                for i, c in enumerate(results)
            ],
        ),
        "",
    ]
    for i, c in enumerate(results):
        lines += [
            f"### {i + 1}. `{c['key']}`: {c['verdict']}",
            "",
            f"> {c['claim']}",
            "",
            f"Where: {c['where']}. Rule: {c['rule']}."
            + (f" Note: {c['note']}." if c["note"] else ""),
            "",
        ]
        rows = []
        for env, res in c["per_env"].items():
            if not res["checks"]:
                rows.append([env, "—", "", "", "", "", "", res["verdict"]])
            for r in res["checks"]:
                m = r["metric"]
                if "diff" not in r:
                    rows.append([env, r["check"], "", "", "", "", "", r["verdict"]])
                    continue
                n = f"{r['n_a']}" + (f" / {r['n_b']}" if r["n_b"] is not None else "")
                ci = f"[{fmt_value(m, r['ci'][0])}, {fmt_value(m, r['ci'][1])}]"
                verdict = r["verdict"] + (f" ({r['reason']})" if r.get("reason") else "")
                rows.append(
                    [
                        env,
                        r["check"],
                        fmt_value(m, r["a_mean"]),
                        fmt_value(m, r["b_mean"]),
                        f"{fmt_value(m, r['diff'])} {ci}",
                        "" if r["margin"] is None else fmt_value(m, r["margin"]),
                        n,
                        verdict,
                    ]
                )
        lines += _md_table(
            ["env", "check", "A", "B", "A vs B [95% CI]", "margin", "seeds", "verdict"], rows
        )
        env_line = ", ".join(f"{e}: {res['verdict']}" for e, res in c["per_env"].items())
        lines += ["", f"Per environment: {env_line}.", ""]
    lines += ["Claims not checked:", ""] + [f"- {t}" for t in claims.NOT_CHECKED] + [""]
    return lines


def render(results: dict[str, Any], table: Table) -> str:
    """report.md from the aggregated results."""
    grid, runs, comp = results["grid"], results["runs"], results["compute"]
    usual_n = results["usual_seeds"]
    lines = [
        "# TransAM reproduction report",
        "",
        f"Generated {results['generated']} by `transam report` from `{grid['out']}`.",
        "",
        "## How this was run",
        "",
        f"Budget **{grid['budget']}**, partners **{grid.get('partners', 'default')}** (the "
        "population every run trained against; `heldout` evaluations are the shipped held-out "
        "population), settings "
        + (
            ", ".join(f"**{k}={json.dumps(v)}**" for k, v in grid.get("settings", {}).items())
            or "**the defaults**"
        )
        + " (`transam reproduce --set`: what every run changes from the defaults):",
        "",
        *_md_table(
            ["setting", "value"],
            [
                [k, f"{v:,}" if isinstance(v, int) else str(v)]
                for k, v in grid["budget_settings"].items()
                if k != "seeds"  # the count without --seeds; the runs' own seeds follow
            ]
            + [["seeds", ", ".join(map(str, grid.get("seeds", []))) or "none"]],
        ),
        "",
        "Commands (one per invocation, from grid.json):",
        "",
        "```",
        *(comp["commands"] or ["(grid.json records no command)"]),
        "```",
        "",
        f"Compute: {comp['invocations']} invocation(s), wall time "
        + (_hms(comp["wall_seconds"]) if comp["invocations_with_end"] else "unknown")
        + " (h:mm:ss, summed over invocations"
        + (
            f"; {comp['invocations_without_end']} invocation(s) have no end time and are "
            "not counted"
            if comp["invocations_without_end"]
            else ""
        )
        + f"); {_hms(comp['run_seconds_from_logs'])} summed over the runs' own launches "
        "(log/*.jsonl, training + evaluation, overlapping when runs ran in parallel).",
        "",
    ]
    for m in comp["machines"]:
        parts = [
            str(m["platform"]) if m.get("platform") else "",
            f"{m['cpus']} CPUs" if m.get("cpus") else "",
            str(m["cpu"]) if m.get("cpu") else "",
            "ISA " + " ".join(m["cpu_isa"]) if m.get("cpu_isa") else "",
            f"JAX backend {m['jax_backend']}" if m.get("jax_backend") else "",
            "devices " + ", ".join(map(str, m["devices"])) if m.get("devices") else "",
        ]
        lines.append(f"- Machine `{m.get('host', '?')}`: " + "; ".join(p for p in parts if p))
    if comp["failures"]:
        lines += ["", "Failures recorded by the grid, of runs not finished since:", ""]
        lines += [f"- `{f}`" for f in comp["failures"]]
    if comp.get("failures_of_finished_runs"):
        lines += [
            "",
            f"{comp['failures_of_finished_runs']} failure(s) recorded for runs that a later "
            "invocation finished (grid.json's invocations list them).",
        ]
    lines += [
        "",
        "## Runs",
        "",
        f"{runs['expected']} runs in grid.json; {len(runs['finished'])} finished, "
        f"{len(runs['unfinished'])} unfinished, {len(runs['missing'])} missing; "
        f"{len(runs['not_evaluated_train'])} finished run(s) without a final evaluation "
        "(their numbers below are the last training evaluation, marked †).",
        "",
    ]
    for key, what in (
        ("missing", "Missing (not started)"),
        ("unfinished", "Unfinished (learning curves only)"),
        ("not_evaluated_train", "Not evaluated on training partners"),
        ("not_evaluated_heldout", "Not evaluated on held-out partners"),
        ("not_in_grid_json", "Found on disk but not in grid.json"),
    ):
        if runs[key]:
            lines.append(f"- {what}: " + ", ".join(f"`{r}`" for r in runs[key]))
    for rel, problems in runs["problems"].items():
        lines.append(f"- Problems in `{rel}`: " + "; ".join(problems))
    lines += [
        "",
        "## Statistics",
        "",
        CI_METHOD,
        "",
        "Cells read `mean ± std [95% CI]`: the mean over seeds of each seed's final evaluation "
        "(mean over its evaluation episodes), the standard deviation across seeds (ddof 1), "
        f"and the bootstrap CI of the mean. Every cell has n = {usual_n} seeds unless marked "
        "(n=K); with n=1 the interval is the value itself and the std is 0 (no spread can be "
        "estimated from one seed). † = the last evaluation during training (final.json) stands "
        "in for a missing final evaluation for some or all of the cell's seeds.",
        "",
        "## Results",
        "",
        "### Final return (training partners)",
        "",
        *metric_table(table, "return", usual_n),
        "",
        "Spread of returns over evaluation episodes (the paper's “mean and standard deviation "
        "over 100 evaluation episodes”): the standard deviation over one run's episodes, "
        "averaged over seeds.",
        "",
        *_episode_std_table(table),
        "",
        "### Action reconstruction accuracy (%)",
        "",
        ACCURACY_NOTE,
        "",
        "Newest position:",
        "",
        *metric_table(table, ACC_NEWEST, usual_n),
        "",
        "All window positions:",
        "",
        *metric_table(table, ACC_ALL, usual_n),
        "",
        *_levels_md(table, results.get("partner_levels", {})),
        "",
        "### Observation reconstruction MSE",
        "",
        *metric_table(table, "obs_mse", usual_n),
        "",
        *_input_sizes_md(table, usual_n),
        "### Spread ablation (paper Table 1)",
        "",
    ]
    ablation = ["transam", "transam-pool", "transam-fuse", "transam-im"]  # Table 1's rows
    spread = table.get("spread", {})
    rows = [
        [
            f"**{display(m)}**",
            _cell_text(table, "spread", m, "return", usual_n),
            _cell_text(table, "spread", m, ACC_NEWEST, usual_n),
            _cell_text(table, "spread", m, ACC_ALL, usual_n),
        ]
        for m in ablation
    ]
    if any(spread.get(m, {}).get("seeds") for m in ablation):
        header = ["method", "return", "accuracy, newest (%)", "accuracy, all positions (%)"]
        lines += _md_table(header, rows)
        lines += [
            "",
            "Paper: TransAM −48.76 / 85.72, -pool −49.37 / 61.67, -fuse −48.94 / "
            "78.68, -im −49.93 / 72.08 (return / accuracy %). Which accuracy the paper "
            "reports is not stated; the newest-position column is the one compared (see "
            "“Action reconstruction accuracy” above); TransAM-pool has no all-positions value.",
        ]
    else:
        lines.append("_The Spread ablation was not run._")
    lines += [
        "",
        "### Training vs held-out partners",
        "",
        "Return against the training population → return against the held-out population "
        "(partners never seen in training), final evaluation.",
        "",
    ]
    held_envs = [
        e for e in table if any("heldout_return" in c["metrics"] for c in table[e].values())
    ]
    held_methods = _methods_with(table, "heldout_return")
    if held_envs:
        rows = []
        for m in held_methods:
            row = [f"**{display(m)}**"]
            for e in held_envs:
                c = table[e].get(m)
                if c is None or "heldout_return" not in c["metrics"]:
                    row.append("—" if c and c["seeds"] else "not run")
                    continue
                train = c["metrics"].get("return")
                held = fmt_stat("heldout_return", c["metrics"]["heldout_return"], usual_n)
                row.append(f"{fmt_value('return', train['mean']) if train else '—'} → {held}")
            rows.append(row)
        lines += _md_table(["method", *held_envs], rows)
    else:
        lines.append("_No held-out evaluation yet._")
    lines += [
        "",
        "### Partner-identity probe (%)",
        "",
        "Accuracy of a linear probe predicting the partner team from the method's embedding "
        "(held-out episodes of the final evaluation; this analysis is the reproduction's, not "
        "the paper's).",
        "",
        *metric_table(table, "probe_accuracy", usual_n),
    ]
    chance = {
        e: next(
            (c["probe_chance"] for c in table[e].values() if c["probe_chance"] is not None), None
        )
        for e in table
    }
    if any(v is not None for v in chance.values()):
        lines += [
            "",
            "Chance: "
            + ", ".join(f"{e} {100 * v:.1f}" for e, v in chance.items() if v is not None)
            + ".",
        ]
    probe_notes = {
        m: c["probe_note"] for env in table.values() for m, c in env.items() if c["probe_note"]
    }
    for m, note in probe_notes.items():
        lines += ["", f"{display(m)}: {note}."]
    lines += ["", "### Aggregates over environments (stratified bootstrap)", ""]
    agg = results["aggregates"]
    if agg:
        for metric, per_method in agg.items():
            rows = [
                [
                    f"**{display(m)}**",
                    f"{fmt_value(metric, a['mean'])} [{fmt_value(metric, a['lo'])}, "
                    f"{fmt_value(metric, a['hi'])}]",
                    ", ".join(
                        f"{e} (n={n})" for e, n in zip(a["envs"], a["seeds_per_env"], strict=True)
                    ),
                ]
                for m, a in per_method.items()
            ]
            lines += [f"Mean {METRIC_TITLE[metric]} over environments:", ""]
            lines += [*_md_table(["method", "mean [95% CI]", "environments"], rows), ""]
        lines.append(
            "Returns are not aggregated across environments: their scales differ and there is "
            "no agreed reference score to normalise them by."
        )
    else:
        lines.append("_Nothing to aggregate yet._")
    lines += ["", "## Figures", ""]
    captions = {
        "returns": "Evaluation return during training (mean over seeds, 95% CI band).",
        ACC_NEWEST: "Other agents' action reconstruction accuracy (newest position) in the "
        "evaluations during training.",
        "episode": "TransAM across an episode (final evaluation): cumulative reward, action "
        "accuracy, observation MSE per timestep; 95% CI over seeds.",
        "probe": "Partner probe accuracy per timestep; dotted: chance.",
        "pca": "TransAM embeddings, first two principal components, coloured by partner team.",
    }
    for key, rel in results["figures"].items():
        lines += [f"![{captions[key]}]({rel})", "", f"*{captions[key]}*", ""]
    missing_figs = [k for k in FIGURES if k not in results["figures"]]
    if missing_figs:
        lines += [f"Not drawn (no data yet): {', '.join(missing_figs)}.", ""]
    lines += ["## Paper claims", "", *_claims_md(results["claims"])]
    lines += [
        "## Files",
        "",
        "- `results.json`: every number above (per-seed values, curves, claims).",
        "- `marl_eval.json`: marl-eval raw-data format (env → task → algorithm → run → "
        "step_k); each metric list holds the evaluation's episode mean, as per-episode values "
        "are not logged during training.",
        "",
    ]
    return "\n".join(lines)
