"""The figures of ``bench pose`` (the paper's Figs. 4 to 8), drawn from its JSON result: the
paper's method (GPD+RDSR) in red in every figure, the baselines in blue or grey."""

from __future__ import annotations

import pathlib
from collections.abc import Callable
from typing import Any

import numpy as np

from quatmotion.viz import pyplot, save_figure

__all__ = ["figures"]

OURS = "GPD+RDSR"  # the paper's method, drawn in red in every figure
PRECISION = "transition precision (Eq. 37)"

Save = Callable[[Any, str], None]


def figures(
    out: pathlib.Path,
    results: dict[str, Any],
    features: tuple[str, ...],
    learners: tuple[str, ...],
) -> list[str]:
    """Draw every figure of ``results`` beside ``out`` (``<stem>_<dataset>_fig*.png``); their
    file names. ``features`` x ``learners``: the grid of Fig. 6."""
    plt = pyplot()
    written: list[str] = []
    quick = " (quick run)" if results.get("quick") else ""

    def save(fig: Any, suffix: str) -> None:
        written.append(save_figure(fig, out.with_name(f"{out.stem}_{suffix}.png")).name)

    for ds, res in results["datasets"].items():
        tr = res.get("transition")
        if tr:
            pairs = f"{tr['test']['pairs']} test pose pairs from {tr['test']['clips']} clips"
            if any("precision" in e for e in tr["methods"].values()):
                _fig5(plt, save, ds, tr, f"{quick}\n{pairs}")
                _fig6(plt, save, ds, tr, f"{quick}\n{pairs}", features, learners)
            _fig4(plt, save, ds, tr.get("rank_sweep", {}), quick)
            _fig7(plt, save, ds, tr.get("unlabeled_sweep", {}), quick)
        rt = res.get("retrieval")
        if rt and rt["methods"]:
            _fig8(plt, save, ds, rt, quick)
    return written


def _fig5(plt: Any, save: Save, ds: str, tr: dict[str, Any], about: str) -> None:
    """Transition precision of every method (paper Fig. 5)."""
    from matplotlib.patches import Patch

    names = [n for n, e in tr["methods"].items() if "precision" in e]
    fig, ax = plt.subplots(figsize=(max(7, 0.45 * len(names)), 4.5))
    vals = [tr["methods"][n]["precision"] for n in names]
    colors = ["tab:red" if n == OURS else "tab:blue" for n in names]
    ax.bar(range(len(names)), vals, color=colors)
    eq35 = tr.get("baseline_eq35_precision")
    handles = [
        Patch(color="tab:red", label=f"{OURS} (the paper's method)"),
        Patch(color="tab:blue", label="baselines"),
    ]
    if eq35 is not None:
        handles.append(
            ax.axhline(eq35, color="k", ls=":", lw=1, label="Eq. 35 mean joint distance")
        )
    ax.set_xticks(range(len(names)), names, rotation=70, fontsize=8)
    ax.set_ylim(min([*vals, eq35 or 1.0]) - 0.05, 1.0)
    ax.set_xlabel("pose distance (feature + learner, or a fixed distance)")
    ax.set_ylabel(PRECISION)
    ax.set_title(
        f"{ds}: which pose pairs make smooth transitions (paper Fig. 5){about}; higher is better",
        fontsize=10,
    )
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    save(fig, f"{ds}_fig5_transition")


def _fig6(
    plt: Any,
    save: Save,
    ds: str,
    tr: dict[str, Any],
    about: str,
    features: tuple[str, ...],
    learners: tuple[str, ...],
) -> None:
    """Transition precision of features x learners (paper Fig. 6)."""
    grid = np.full((len(learners), len(features)), np.nan)
    for i, lrn in enumerate(learners):
        for j, feat in enumerate(features):
            e = tr["methods"].get(f"{feat}+{lrn}", {})
            if "precision" in e:
                grid[i, j] = e["precision"]
    if not np.isfinite(grid).any():
        return
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    im = ax.imshow(grid, cmap="viridis")
    ax.set_xticks(range(len(features)), features)
    ax.set_yticks(range(len(learners)), learners)
    ax.set_xlabel("pose feature")
    ax.set_ylabel("metric learner")
    mid = 0.5 * (np.nanmin(grid) + np.nanmax(grid))
    for (i, j), v in np.ndenumerate(grid):
        if np.isfinite(v):
            ink = "k" if v > mid else "w"  # readable on viridis
            ax.text(j, i, f"{v:.3f}", ha="center", va="center", color=ink, fontsize=8)
    fig.colorbar(im, label=PRECISION)
    ax.set_title(f"{ds}: features x learners (paper Fig. 6){about}", fontsize=10)
    save(fig, f"{ds}_fig6_features_learners")


def _fig4(plt: Any, save: Save, ds: str, sweep: dict[str, Any], quick: str) -> None:
    """The paper's method against its rank (paper Fig. 4)."""
    pts = [(int(r), e["precision"]) for r, e in sweep.items() if "precision" in e]
    if not pts:
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    ranks, precisions = zip(*sorted(pts), strict=True)
    ax.plot(ranks, precisions, "o-", color="tab:red", label=OURS)
    ax.set_xscale("log")
    ax.set_xticks(ranks, [str(r) for r in ranks])
    ax.minorticks_off()
    ax.set_xlabel("rank of W (dimension of the learned projection, log scale)")
    ax.set_ylabel(PRECISION)
    ax.set_title(f"{ds}: {OURS} against its rank (paper Fig. 4){quick}", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    save(fig, f"{ds}_fig4_rank")


def _fig7(plt: Any, save: Save, ds: str, sweep: dict[str, Any], quick: str) -> None:
    """Precision against the unlabeled poses used (paper Fig. 7)."""
    if not any(sweep.values()):
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, ent in sweep.items():
        pts = [(int(n), e["precision"]) for n, e in ent.items() if "precision" in e]
        if pts:
            color = "tab:red" if name == OURS else "tab:blue"
            ax.plot(*zip(*sorted(pts), strict=True), "o-", label=name, color=color)
    ax.set_xlabel("unlabeled poses N' used in training")
    ax.set_ylabel(PRECISION)
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    ax.set_title(f"{ds}: effect of unlabeled data (paper Fig. 7){quick}", fontsize=10)
    save(fig, f"{ds}_fig7_unlabeled")


def _fig8(plt: Any, save: Save, ds: str, rt: dict[str, Any], quick: str) -> None:
    """Pose retrieval precision@s of every method (paper Fig. 8)."""
    curves = {name: e["precision_at"] for name, e in rt["methods"].items() if "precision_at" in e}
    if not curves:
        return
    fig, ax = plt.subplots(figsize=(7, 4.5))
    # 27 curves cannot each have a readable colour: the paper's method, the best other method
    # (mean precision over scopes) and the oracle stand out; the rest are grey.
    others = {n: np.mean(list(c.values())) for n, c in curves.items() if n != OURS}
    best = max(others, key=others.get) if others else None
    grey_label = f"other methods ({max(0, len(others) - 1)})"
    for name, curve in curves.items():
        xs, ys = [int(s) for s in curve], list(curve.values())
        if name == OURS:
            ax.plot(xs, ys, "o-", color="tab:red", lw=2.2, label=name)
        elif name == best:
            ax.plot(xs, ys, "s-", color="tab:blue", lw=1.8, label=f"{name} (best other)")
        else:
            ax.plot(xs, ys, "-", color="0.7", lw=0.8, label=grey_label)
            grey_label = "_nolegend_"
    if "oracle" in rt:
        ax.plot(rt["scopes"], rt["oracle"], "k--", lw=1, label="oracle (all correct first)")
    if "chance" in rt:
        ax.axhline(rt["chance"], color="k", ls=":", lw=1, label="chance")
    ax.set_xlabel("scope s (number of poses retrieved)")
    ax.set_ylabel("precision@s (fraction of the s poses that are correct)")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    ax.set_title(
        f"{ds}: pose retrieval (paper Fig. 8){quick}\n"
        f"{rt['test_poses']} query poses; higher is better",
        fontsize=10,
    )
    save(fig, f"{ds}_fig8_retrieval")
