"""The paper's figures from the aggregated cells: one panel per environment, one line per
method, shaded 95% bootstrap CI across seeds. A figure with no data is not drawn.

Drawn on ``matplotlib.figure.Figure`` directly (no pyplot): no global backend or figure state,
so the report can be built inside any process, and files are written atomically.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from transam.registry import display, env_title, method_entry, method_names
from transam.reproduce.report.aggregate import ACC_NEWEST, LEVELS_BY_STEP
from transam.reproduce.report.load import METHOD_ORDER, RunData
from transam.rundir import write_atomic

FONT: Any = {  # (Any: matplotlib types rc keys as a Literal)
    "font.size": 11,
    "axes.titlesize": 12,
    "axes.labelsize": 11,
    "legend.fontsize": 10,
}
PANEL = (4.4, 3.4)
MIN_WIDTH = 7.0


def _style(method: str) -> dict[str, Any]:
    """A fixed colour per method across figures; ablations dashed."""
    import matplotlib as mpl

    i = METHOD_ORDER.index(method) if method in METHOD_ORDER else len(METHOD_ORDER)
    color = mpl.colormaps["tab10"](i % 10)
    kind = method_entry(method).kind if method in method_names() else None
    ablation, main = kind == "ablation", kind == "main"
    width = 2.2 if main else 1.5
    return {
        "color": color,
        "linestyle": "--" if ablation else "-",
        "linewidth": width,
        "zorder": 3 if main else 2,  # TransAM on top
    }


def _arr(xs: Sequence[float | None]) -> np.ndarray:
    return np.array([np.nan if x is None else x for x in xs], dtype=float)


def _band(ax: Axes, x: Sequence[float], curve: dict[str, Any], label: str, **style: Any) -> None:
    mean, lo, hi = _arr(curve["mean"]), _arr(curve["lo"]), _arr(curve["hi"])
    marker = "o" if len(x) <= 12 else None
    ax.plot(x, mean, label=label, marker=marker, markersize=3.5, **style)
    ax.fill_between(x, lo, hi, color=style["color"], alpha=0.18, linewidth=0)


def _save(fig: Figure, path: Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, buf.getvalue())
    return path


def _legend(fig: Figure, axes: Sequence[Axes]) -> None:
    """One legend under the panels, with every label used in any panel."""
    seen: dict[str, Any] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            seen.setdefault(label, handle)
    if seen:
        ncol = max(1, min(len(seen), 5, int(fig.get_figwidth() / 1.5)))
        fig.legend(list(seen.values()), list(seen), loc="outside lower center", ncol=ncol)


def _panels(n_rows: int, n_cols: int, sharex: bool = False) -> tuple[Figure, np.ndarray]:
    import matplotlib as mpl

    with mpl.rc_context(FONT):
        width = max(PANEL[0] * n_cols, MIN_WIDTH)  # room for the title and the legend
        fig = Figure(figsize=(width, PANEL[1] * n_rows + 0.9), layout="constrained")
        share: Literal["col"] | bool = "col" if sharex else False
        axes = np.atleast_2d(fig.subplots(n_rows, n_cols, squeeze=False, sharex=share))
    return fig, axes


def training_curves(
    table: dict[str, dict[str, Any]], metric: str, ylabel: str, title: str, path: Path
) -> Path | None:
    """Fig. 3 / Fig. 4 (top): a metric logged during training vs environment steps."""
    import matplotlib as mpl

    envs = [e for e, cells in table.items() if any(metric in c["curves"] for c in cells.values())]
    if not envs:
        return None
    with mpl.rc_context(FONT):
        fig, axes = _panels(1, len(envs))
        for ax, env in zip(axes[0], envs, strict=True):
            for method, c in table[env].items():
                if metric in c["curves"]:
                    curve = c["curves"][metric]
                    _band(ax, curve["step"], curve, display(method), **_style(method))
            ax.set_title(env_title(env))
            ax.set_xlabel("environment steps (controlled agent)")
            ax.set_ylabel(ylabel)
            ax.grid(alpha=0.3)
            ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 3))
        fig.suptitle(title)
        _legend(fig, list(axes[0]))
        return _save(fig, path)


EPISODE_ROWS = (
    ("cum_return", "cumulative reward ↑"),
    (ACC_NEWEST, "action accuracy (newest position) ↑"),
    ("obs_mse", "observation MSE ↓"),
)


def episode_evolution(
    table: dict[str, dict[str, Any]],
    method: str,
    path: Path,
    levels: dict[str, dict[str, Any] | None] | None = None,
) -> Path | None:
    """Fig. 5: one method's cumulative reward, action accuracy and observation MSE vs the
    timestep within the episode (final evaluation), CI across seeds; the accuracy panel also
    shows the population's per-step memoryless level where ``levels`` records one."""
    import matplotlib as mpl

    envs = [e for e, cells in table.items() if cells.get(method, {}).get("per_step")]
    rows = [
        (k, label)
        for k, label in EPISODE_ROWS
        if any(k in table[e][method]["per_step"] for e in envs)
    ]
    if not envs or not rows:
        return None
    with mpl.rc_context(FONT):
        fig, axes = _panels(len(rows), len(envs), sharex=True)
        style = _style(method)
        for j, env in enumerate(envs):
            per_step = table[env][method]["per_step"]
            for i, (key, label) in enumerate(rows):
                ax = axes[i, j]
                if key in per_step:
                    _band(ax, per_step[key]["t"], per_step[key], display(method), **style)
                    recorded = (levels or {}).get(env) or {}
                    drawn = [
                        (recorded[k], name)
                        for k, name in LEVELS_BY_STEP
                        if recorded.get(k) and key == ACC_NEWEST
                    ]
                    for (level, name), ls in zip(drawn, (":", "--", "-."), strict=False):
                        y = [np.nan if v is None else v for v in level]
                        ax.plot(range(len(y)), y, color="black", linestyle=ls, lw=0.8, label=name)
                    if drawn:
                        ax.legend(loc="best", fontsize="small", title="memoryless")
                else:
                    ax.text(
                        0.5,
                        0.5,
                        "not predicted",
                        ha="center",
                        va="center",
                        transform=ax.transAxes,
                        color="grey",
                    )
                if i == 0:
                    seeds = max(max(c["n"]) for c in per_step.values() if c["n"])
                    ax.set_title(f"{env_title(env)} (n={seeds})")
                if i == len(rows) - 1:
                    ax.set_xlabel("timestep in episode")
                if j == 0:
                    ax.set_ylabel(label)
                ax.grid(alpha=0.3)
        fig.suptitle(f"{display(method)} across an episode (95% CI over seeds)")
        return _save(fig, path)


def probe_curves(table: dict[str, dict[str, Any]], path: Path) -> Path | None:
    """Partner-identity probe accuracy vs timestep, one line per method, chance dashed."""
    import matplotlib as mpl

    envs = [
        e
        for e, cells in table.items()
        if any("probe_accuracy" in c["per_step"] for c in cells.values())
    ]
    if not envs:
        return None
    with mpl.rc_context(FONT):
        fig, axes = _panels(1, len(envs))
        for ax, env in zip(axes[0], envs, strict=True):
            chances = []
            for method, c in table[env].items():
                if "probe_accuracy" in c["per_step"]:
                    curve = c["per_step"]["probe_accuracy"]
                    _band(ax, curve["t"], curve, display(method), **_style(method))
                    if c["probe_chance"] is not None:
                        chances.append(c["probe_chance"])
            if chances:
                ax.axhline(np.mean(chances), color="black", linestyle=":", label="chance")
            ax.set_title(env_title(env))
            ax.set_xlabel("timestep in episode")
            ax.set_ylabel("partner probe accuracy")
            ax.grid(alpha=0.3)
        fig.suptitle("Partner probe accuracy (linear probe on the embedding)")
        _legend(fig, list(axes[0]))
        return _save(fig, path)


def pca_scatter(runs: list[RunData], method: str, path: Path) -> Path | None:
    """The first two principal components of one method's embeddings (first seed with a PCA
    file, training partners), coloured by partner team."""
    import matplotlib as mpl

    chosen: dict[str, RunData] = {}
    for run in runs:
        if run.method == method and "train" in run.pca and run.env not in chosen:
            chosen[run.env] = run
    if not chosen:
        return None
    with mpl.rc_context(FONT):
        fig, axes = _panels(1, len(chosen))
        for ax, (env, run) in zip(axes[0], chosen.items(), strict=True):
            proj = run.pca["train"]
            teams = sorted(set(proj.partner.tolist()))
            cmap = mpl.colormaps["tab20" if len(teams) > 10 else "tab10"]
            for k, team in enumerate(teams):
                sel = proj.partner == team
                names = proj.team_names
                label = names[team] if names and 0 <= team < len(names) else f"partner {team}"
                ax.scatter(
                    *proj.coords[sel].T, s=10, alpha=0.7, color=cmap(k % cmap.N), label=label
                )
            ev = proj.explained_variance
            pc = [
                f"PC{i + 1}" + (f" ({100 * ev[i]:.0f}% var.)" if ev and len(ev) > i else "")
                for i in range(2)
            ]
            ax.set_title(f"{env_title(env)}, seed {run.seed}")
            ax.set_xlabel(pc[0])
            ax.set_ylabel(pc[1])
            ax.grid(alpha=0.3)
            ax.legend(
                title="partner",
                fontsize=7,
                title_fontsize=8,
                markerscale=1.5,
                loc="center left",
                bbox_to_anchor=(1.0, 0.5),
                ncol=1 + len(teams) // 16,
            )
        fig.suptitle(f"{display(method)} embeddings: first two principal components")
        return _save(fig, path)
