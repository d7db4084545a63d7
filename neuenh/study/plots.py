"""The report's figures (matplotlib, Agg): speed against error with the Pareto front, the search,
held-out error per material, and one render grid per material. Every figure is written atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..files import atomic_write
from .summary import ModelSummary

_COLOURS = {"enhanced": "#d62728", "analytical": "#1f77b4", "residual": "#2ca02c", "neural": "#9467bd"}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    try:
        return atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110))
    finally:
        _plt().close(fig)


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point beats on both axes (x higher is better, y lower is
    better), sorted by x."""
    front = [i for i, (x, y) in enumerate(points)
             if not any((x2 >= x and y2 <= y) and (x2 > x or y2 < y) for x2, y2 in points)]
    return sorted(front, key=lambda i: points[i][0])


def speed_vs_error(path: Path, models: list[ModelSummary]) -> Path:
    """Three panels (evaluation rate, render rate, parameters per material against error), each
    with its Pareto front."""
    plt = _plt()
    panels = [("evals_per_s", "BRDF evaluations per second (1 thread)", "log_l1", "median held-out log-L1", True),
              ("rays_per_s", "render throughput (rays per second)", "delta_e", "median ΔE_ITP (BT.2124) of renders", True),
              ("params_per_material", "parameters per material (fewer is better →)", "log_l1",
               "median held-out log-L1", False)]
    fig, axes = plt.subplots(1, 3, figsize=(16, 5), constrained_layout=True)
    for ax, (xkey, xlabel, ykey, ylabel, higher_better) in zip(axes, panels):
        xs = [getattr(m, xkey) for m in models]
        ys = [getattr(m, ykey) for m in models]
        signed = [(x if higher_better else -x, y) for x, y in zip(xs, ys)]
        front = pareto_front(signed)
        ax.plot([xs[i] for i in front], [ys[i] for i in front], "--", color="#888", zorder=1, label="Pareto front")
        for m, x, y in zip(models, xs, ys):
            ax.scatter([x], [y], s=60, color=_COLOURS.get(m.family, "#333"), zorder=2,
                       edgecolor="black" if m.family == "enhanced" else "none")
            ax.annotate(m.label, (x, y), textcoords="offset points", xytext=(5, 4), fontsize=8)
        ax.set_xscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        if not higher_better:
            ax.invert_xaxis()
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    fig.suptitle("Speed against error on the RGL materials (up and right on the Pareto front is better)")
    return _save(fig, path)


def search_path(path: Path, rounds: list[dict]) -> Path:
    """Every candidate's validation loss against its neural weights, round by round, with the
    path taken (the winners) drawn through them."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 5.5), constrained_layout=True)
    cmap = plt.get_cmap("viridis")
    winners = []
    for k, r in enumerate(rounds):
        colour = cmap(k / max(len(rounds) - 1, 1))
        c = [x for x in r["candidates"] if x.get("val_loss") is not None]
        ax.scatter([x["weights"] for x in c], [x["val_loss"] for x in c], s=18, color=colour, alpha=0.7,
                   label=f"round {r['index']}" + (" (polish)" if r.get("kind") == "polish" else ""))
        win = next(x for x in r["candidates"] if x["state"] == r["winner_state"])
        winners.append((win["weights"], win["val_loss"], r["winner_state"]))
    ax.plot([w[0] for w in winners], [w[1] for w in winners], "-o", color="#d62728", lw=1.5, ms=5, label="path taken")
    for w, v, state in winners:
        ax.annotate(state, (w, v), textcoords="offset points", xytext=(4, -10), fontsize=7, color="#d62728")
    ax.set_xscale("symlog", linthresh=100)
    ax.set_yscale("log")
    ax.set_xlabel("neural weights of the state (cost)")
    ax.set_ylabel("validation log-L1 after the round's training")
    ax.set_title("The hypercube search of the shipped enhanced GGX")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    return _save(fig, path)


def efficiency(path: Path, points: list, labels: dict[str, str]) -> Path:
    """Median held-out log-L1 against the number of fit samples, one panel per protocol, one line per
    model (``study.efficiency``)."""
    from .efficiency import medians

    plt = _plt()
    protocols = list(dict.fromkeys(p.protocol for p in points))
    fig, axes = plt.subplots(1, len(protocols), figsize=(6.5 * len(protocols), 4.6), constrained_layout=True,
                             squeeze=False)
    styles = {"enhanced": ("#d62728", "o"), "enhanced-adaptive": ("#ff7f0e", "v"), "ggx": ("#1f77b4", "s"),
              "nbrdf": ("#9467bd", "^")}
    for ax, protocol in zip(axes[0], protocols):
        for name, by_n in medians(points, protocol).items():
            colour, marker = styles.get(name, ("#2ca02c", "D"))
            ax.plot(list(by_n), list(by_n.values()), marker=marker, color=colour, label=labels.get(name, name))
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("fit samples per material")
        ax.set_ylabel("median held-out log-L1")
        ax.set_title(f"protocol: {protocol}")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.suptitle("Data efficiency on the RGL materials: where does the shared model's prior pay?")
    return _save(fig, path)


def heldout_bars(path: Path, materials: list[str], models: list[ModelSummary], values: dict[str, list[float]]) -> Path:
    """Held-out log-L1 per material (groups) and model (bars), log scale."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(14, 5), constrained_layout=True)
    width = 0.8 / len(models)
    x = np.arange(len(materials))
    for j, m in enumerate(models):
        ax.bar(x + (j - (len(models) - 1) / 2) * width, values[m.name], width,
               color=_COLOURS.get(m.family, "#333"), alpha=0.45 + 0.55 * (m.family == "enhanced"),
               edgecolor="black", linewidth=0.4, label=m.label)
    ax.set_xticks(x, [name.replace("_rgb", "") for name in materials], rotation=15)
    ax.set_yscale("log")
    ax.set_ylabel("held-out log-L1 (lower is better)")
    ax.legend(fontsize=8, ncol=4)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def render_grid(path: Path, title: str, columns: list[tuple[str, np.ndarray]], truth: np.ndarray,
                mask: np.ndarray) -> Path:
    """Top row: the truth then each column's render (tone-mapped); bottom row: each column's
    relative luminance error against the truth, one shared colour scale."""
    from ..render.output import error_map, tonemap

    plt = _plt()
    n = len(columns) + 1
    fig, axes = plt.subplots(2, n, figsize=(2.6 * n, 5.6), constrained_layout=True)
    axes[0, 0].imshow(tonemap(truth))
    axes[0, 0].set_title("measured (truth)", fontsize=9)
    axes[1, 0].axis("off")
    errors = [np.where(mask, error_map(truth, image), np.nan) for _, image in columns]
    vmax = float(np.nanpercentile(np.concatenate([e[np.isfinite(e)] for e in errors]), 99)) or 1.0
    shown = None
    for j, ((label, image), error) in enumerate(zip(columns, errors), start=1):
        axes[0, j].imshow(tonemap(image))
        axes[0, j].set_title(label, fontsize=9)
        shown = axes[1, j].imshow(error, cmap="inferno", vmin=0, vmax=vmax)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(shown, ax=list(axes[1, 1:]), shrink=0.8, label="relative luminance error")
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)
