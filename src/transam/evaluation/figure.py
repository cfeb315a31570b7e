"""The figure of a final evaluation (eval_PARTNERS.png): per-step curves, the probe's
accuracy and the projection of the embeddings, where present."""

from __future__ import annotations

import io
from typing import Any

import numpy as np

from transam.models.base import ACC_ALL, ACC_NEWEST


def evaluation_figure(
    result: dict[str, Any],
    teams: tuple[str, ...],
    labels: np.ndarray,
    pca: tuple[np.ndarray, np.ndarray] | None,
) -> bytes:
    """The PNG: per-step curves, probe accuracy and the projection (where present)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    per = result["per_step"]
    curves = [("cum_return", "cumulative reward")]
    curves += [(ACC_NEWEST, "action accuracy, newest position")]
    curves += [(ACC_ALL, "action accuracy, all window positions")]
    curves += [("obs_mse", "observation MSE")]
    panels = [(k, label) for k, label in curves if k in per]
    if "probe" in result:
        panels.append(("probe", "partner probe accuracy"))
    if pca is not None:
        panels.append(("pca", "embeddings at the last step (PCA)"))
    cols = min(3, len(panels))
    rows = -(-len(panels) // cols)
    # Fixed margins, not matplotlib's constrained layout: that doubles the drawing time (0.8
    # against 1.4 s a figure), and every evaluation draws one. The legend of the projection
    # (the last panel) sits to its right: in the empty panel beside it, or in a margin.
    full_row = len(panels) % cols == 0
    legend_in = 1.7 * (1 + len(teams) // 16) if pca is not None and full_row else 0.0
    width, height = max(4.6 * cols, 6.0) + legend_in, 3.6 * rows + 0.4
    fig = Figure(figsize=(width, height))
    fig.subplots_adjust(
        left=0.8 / width,
        right=1 - (0.15 + legend_in) / width,
        bottom=0.5 / height,
        top=1 - 0.75 / height,
        wspace=0.9 / 4.6 * cols / max(cols - 1, 1) if cols > 1 else 0.2,
        hspace=0.9 / 3.6,
    )
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    steps = np.arange(len(per["cum_return"]))
    for ax, (key, label) in zip(axes, panels, strict=False):
        if key == "pca":
            assert pca is not None
            coords = pca[0]
            cmap = matplotlib.colormaps["tab20" if len(teams) > 10 else "tab10"]
            for p in np.unique(labels):
                sel = labels == p
                ax.scatter(*coords[sel].T, s=14, color=cmap(int(p) % cmap.N), label=teams[p])
            ev = result["pca"]["explained_variance"]
            ax.set_xlabel(f"PC1 ({100 * ev[0]:.0f}% var.)")
            ax.set_ylabel(f"PC2 ({100 * ev[1]:.0f}% var.)")
            ax.legend(
                fontsize=6,
                title="partner",
                title_fontsize=7,
                loc="center left",
                bbox_to_anchor=(1.0, 0.5),
                ncol=1 + len(teams) // 16,
            )
        elif key == "probe":
            probe = result["probe"]
            vals = [np.nan if v is None else v for v in probe["per_step"]]
            ax.plot(steps, vals, label="test accuracy")
            ax.axhline(probe["chance"], color="grey", ls="--", label="chance (majority)")
            ax.set_ylim(0.0, 1.02)
            ax.set_xlabel("step t in episode")
            ax.set_ylabel("accuracy")
            ax.legend(fontsize=7)
        else:
            vals = [np.nan if v is None else v for v in per[key]]
            ax.plot(steps, vals, label=result["method"])
            ax.set_xlabel("step t in episode")
            ax.set_ylabel(label)
            ax.legend(fontsize=7)
        ax.set_title(label, fontsize=9)
    for ax in axes[len(panels) :]:
        ax.set_visible(False)
    fig.suptitle(
        f"{result['env']} / {result['method']} seed {result['seed']}, step {result['step']:,}\n"
        f"{result['partners']} partners ({result['population_name']}), "
        f"{result['episodes']} episodes",
        fontsize=10,
    )
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()
