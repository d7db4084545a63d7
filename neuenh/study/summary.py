"""The study's outcome: per material every contender's result, per model the medians, and the
document (``RESULTS.md``) a summary renders of itself."""

from __future__ import annotations

import statistics
from dataclasses import asdict, dataclass, field

import numpy as np

from .comparison import ContenderResult
from .efficiency import CurvePoint, crossover, medians, wins
from .registry import ENHANCED, ENHANCED_ADAPTIVE, ContenderInfo
from .targets import Target, issue23_targets

__all__ = ["MaterialResult", "ModelSummary", "StudySummary"]


@dataclass
class MaterialResult:
    """One material: every contender fitted, measured and rendered (the images are for the figures,
    not the JSON)."""

    material: str
    n_fit: int
    n_test: int
    split: str
    results: list[ContenderResult]
    truth: np.ndarray | None = field(default=None, repr=False)  # (H, W, 3) linear render
    mask: np.ndarray | None = field(default=None, repr=False)
    images: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    curve: list[CurvePoint] = field(default_factory=list, repr=False)  # data efficiency (study.efficiency)

    def by_name(self) -> dict[str, ContenderResult]:
        return {r.contender: r for r in self.results}

    def to_json(self) -> dict:
        return {"material": self.material, "n_fit": self.n_fit, "n_test": self.n_test, "split": self.split,
                "results": [r.row() for r in self.results], "efficiency": [p.row() for p in self.curve]}


@dataclass(frozen=True)
class ModelSummary:
    """One model over every material: medians, except the render rate (total rays / total time)."""

    name: str
    label: str
    family: str
    log_l1: float
    mean_log_l1: float
    ssim: float
    delta_e: float
    evals_per_s: float
    rays_per_s: float
    fit_s: float
    params_per_material: int  # the median over materials (an adaptive fit's vary with its chosen capacity)
    shared_weights: int
    params_range: tuple[int, int] = (0, 0)  # the fewest and most parameters per material

    @property
    def params(self) -> str:
        """Parameters per material as the tables show them: the count, or the median and range."""
        low, high = self.params_range
        return f"{self.params_per_material:,}" if low == high else f"{self.params_per_material:,} ({low:,}–{high:,})"

    @classmethod
    def over(cls, info: ContenderInfo, materials: list[MaterialResult]) -> "ModelSummary":
        rows = [m.by_name()[info.name] for m in materials]
        return cls(name=info.name, label=info.label, family=info.family,
                   log_l1=statistics.median(r.heldout_log_l1 for r in rows),
                   mean_log_l1=statistics.fmean(r.heldout_log_l1 for r in rows),
                   ssim=statistics.median(r.ssim for r in rows),
                   delta_e=statistics.median(r.delta_e_itp for r in rows),
                   evals_per_s=statistics.median(r.evals_per_s for r in rows),
                   rays_per_s=sum(r.rays for r in rows) / sum(r.render_s for r in rows),
                   fit_s=statistics.median(r.fit_s for r in rows),
                   params_per_material=round(statistics.median(r.params_per_material for r in rows)),
                   shared_weights=rows[0].shared_weights,
                   params_range=(min(r.params_per_material for r in rows), max(r.params_per_material for r in rows)))


def _rate(x: float) -> str:
    return f"{x / 1e6:.2f} M" if x >= 1e6 else f"{x / 1e3:.0f} k"


@dataclass(frozen=True)
class StudySummary:
    command: str      # the command that regenerates it
    generated: str    # date
    wall_s: float
    settings: dict    # what the numbers depend on (samples, render size, seed, ...)
    enhanced: dict    # the enhanced model: model, state, formula, weights
    models: list[ModelSummary]
    enhanced_beats_ggx: int
    median_reduction_vs_ggx: float
    render_ratio_enhanced_to_ggx: float
    eval_ratio_enhanced_to_ggx: float

    @classmethod
    def of(cls, materials: list[MaterialResult], infos: list[ContenderInfo], *, command: str, generated: str,
           wall_s: float, settings: dict, enhanced: dict) -> "StudySummary":
        models = [ModelSummary.over(info, materials) for info in infos]
        by_name = {m.name: m for m in models}
        reductions = [1.0 - m.by_name()[ENHANCED].heldout_log_l1 / m.by_name()["ggx"].heldout_log_l1
                      for m in materials]
        return cls(command=command, generated=generated, wall_s=round(wall_s, 1), settings=settings,
                   enhanced=enhanced, models=models, enhanced_beats_ggx=sum(x > 0 for x in reductions),
                   median_reduction_vs_ggx=statistics.median(reductions),
                   render_ratio_enhanced_to_ggx=by_name[ENHANCED].rays_per_s / by_name["ggx"].rays_per_s,
                   eval_ratio_enhanced_to_ggx=by_name[ENHANCED].evals_per_s / by_name["ggx"].evals_per_s)

    def to_json(self, materials: list[MaterialResult]) -> dict:
        return {**asdict(self), "materials": [m.to_json() for m in materials]}

    def markdown(self, materials: list[MaterialResult], provenance: dict) -> str:
        """RESULTS.md: held-out error, render metrics, speed against error, the search, the grids."""
        return "\n".join([*self._heldout(materials), *self._others(materials), *self._near_away(materials),
                          *self._renders(materials),
                          *self._speed(), *self._efficiency(materials), *_search(provenance.get("search")),
                          *_grids(materials)])

    def _others(self, materials: list[MaterialResult]) -> list[str]:
        """The paper's other enhancements against the models they enhance, when measured."""
        from .registry import OTHER_ENHANCED

        measured = [n for n in OTHER_ENHANCED if n in materials[0].by_name()]
        if not measured:
            return []
        lines = ["### Enhancing other models", "",
                 "The same search run on Cook-Torrance and Ward (`examples/reference-cook_torrance.yaml`, "
                 "`examples/reference-ward.yaml`, the same training data), each fitted and measured as above "
                 "beside the analytical model it enhances.", "",
                 "| model | median held-out log-L1 | its original's | median reduction | ahead on |",
                 "|---|---:|---:|---:|---:|"]
        for name in measured:
            label, original = OTHER_ENHANCED[name]
            ours = [m.by_name()[name].heldout_log_l1 for m in materials]
            base = [m.by_name()[original].heldout_log_l1 for m in materials]
            reductions = [1 - a / b for a, b in zip(ours, base)]
            lines.append(f"| {label} | {statistics.median(ours):.4f} | {statistics.median(base):.4f} | "
                         f"{100 * statistics.median(reductions):.1f} % | {sum(r > 0 for r in reductions)} of "
                         f"{len(materials)} |")
        return [*lines, ""]

    def _near_away(self, materials: list[MaterialResult]) -> list[str]:
        """The held-out error split at the mirror direction (the test pairs of the main protocol), with
        each model's parameters per material and fit time beside it."""
        lines = ["### Near and away from the mirror direction", "",
                 "The same held-out log-L1, over the test pairs whose half vector lies within 10° of the normal "
                 "(*near*: where highlights are, a sixth of the uniform pairs) and over the others (*away*). Medians "
                 "over the materials; beside them each model's parameters per material (median, and range when "
                 "its fit chooses a capacity per material) and its fit time.", "",
                 "| model | near | away | all | params / material | fit (s) |", "|---|---:|---:|---:|---:|---:|"]
        for info in self.models:
            rows = [m.by_name()[info.name] for m in materials]
            med = lambda f: statistics.median(getattr(r, f) for r in rows)  # noqa: E731
            lines.append(f"| {info.label} | {med('heldout_near'):.4f} | {med('heldout_away'):.4f} | "
                         f"{med('heldout_log_l1'):.4f} | {info.params} | {info.fit_s:.1f} |")
        return [*lines, ""]

    def _efficiency(self, materials: list[MaterialResult]) -> list[str]:
        points = [p for m in materials for p in m.curve]
        if not points:
            return []
        labels = {x.name: x.label for x in self.models}
        speed = {x.name: x.evals_per_s for x in self.models}
        enhanced = [x.name for x in self.models if x.name in (ENHANCED, ENHANCED_ADAPTIVE)]
        n = len(materials)
        threshold = (3 * n + 3) // 4  # 6 of 8
        lines = ["## Data efficiency: held-out error against the number of fit samples", "",
                 "Each model fitted to 100 to 10,000 measurements of each material and tested on the same "
                 f"{self.settings['test_samples']:,} others, under two protocols (`neuenh.study.efficiency`): "
                 "*uniform* in the four Rusinkiewicz angles, as above, and *mirror*: half the fit and test pairs "
                 "near the mirror direction (half vector within 10° of the normal), the way the reference values "
                 "of ../shared draw theirs. Medians over the materials; beside each model its evaluation speed "
                 "(specialized, one thread, from the table above), and below each table its parameters per "
                 "material (at the capacity each fit chose) and fit time at every size.", ""]
        for protocol in dict.fromkeys(p.protocol for p in points):
            table = medians(points, protocol)
            near, away = medians(points, protocol, "near"), medians(points, protocol, "away")
            params, fit_s = medians(points, protocol, "params_per_material"), medians(points, protocol, "fit_s")
            sizes = sorted({p.n_fit for p in points if p.protocol == protocol})
            row = lambda label, cells: f"| {label} | | " + " | ".join(cells) + " |"  # noqa: E731
            lines += [f"### Protocol: {protocol}", "",
                      "| model | evaluations/s | " + " | ".join(f"{s:,}" for s in sizes) + " |",
                      "|---|---:|" + "---:|" * len(sizes)]
            for name, by_n in table.items():
                lines.append(f"| {labels.get(name, name)} | {_rate(speed[name]) if name in speed else ''} | "
                             + " | ".join(f"{by_n.get(s, float('nan')):.4f}" for s in sizes) + " |")
            for name in enhanced:
                ahead = wins(points, protocol, name, "nbrdf")
                lines.append(row(f"*{labels[name]}: ahead of NBRDF on*",
                                 [f"{ahead[s][0]}/{ahead[s][1]}" if s in ahead else "" for s in sizes]))
            for name in [*enhanced, "nbrdf"]:
                lines.append(row(f"*near / away, {labels.get(name, name)}*",
                                 [f"{near[name][s]:.3f} / {away[name][s]:.3f}" if s in near.get(name, {}) else ""
                                  for s in sizes]))
            lines += ["", f"Parameters per material / fit seconds (medians over the materials), protocol {protocol}:",
                      "", "| model | " + " | ".join(f"{s:,}" for s in sizes) + " |", "|---|" + "---:|" * len(sizes)]
            for name in table:
                lines.append(f"| {labels.get(name, name)} | " + " | ".join(
                    f"{params[name][s]:,.0f} / {fit_s[name][s]:.1f} s" if s in params[name] else "" for s in sizes) + " |")
            lines.append("")
            for name in enhanced:
                cross = crossover(points, protocol, name, "nbrdf", threshold)
                lines.append(f"Largest fit-set size at which {labels[name]} is ahead of NBRDF on at least "
                             f"{threshold} of {n} materials: **{f'{cross:,}' if cross else 'none'}**.")
            lines.append("")
        return [*lines, *self._standing(points), "![held-out error against fit samples](img/results/efficiency.png)", ""]

    def _standing(self, points: list[CurvePoint]) -> list[str]:
        """Issue 23's targets (``study.targets``), measured by the curves above."""
        rows = issue23_targets(points)
        return ["### Where the shared model stands", "",
                "Issue 23's targets, medians over the materials of the curves above (the scene example's, NBRDF "
                "chosen for at most 2 of 8, is in docs/scene-example/plan.md).", "",
                *Target.HEADER, *(t.markdown() for t in rows), ""]

    def _heldout(self, materials: list[MaterialResult]) -> list[str]:
        names, labels = [m.name for m in self.models], [m.label for m in self.models]
        s, e = self.settings, self.enhanced
        scene = "a sphere on a grey ground plane (shadows both ways)" if s.get("scene", "ball") == "ball" else "a sphere"
        lines = [
            "# Results: the enhanced GGX on real measured materials", "",
            f"Regenerate everything on this page (tables, figures, `results.json`) with `{self.command}` "
            f"({self.wall_s / 60:.0f} min on this 2-core machine, {s['jobs']} materials at a time; generated "
            f"{self.generated}).", "",
            f"**Materials:** the {len(materials)} EPFL RGL materials of `../shared/data/rgl` (Dupuy & Jakob 2018), "
            "never seen in training. **Protocol:** every model is fitted per material to the same "
            f"{s['fit_samples']:,} measurements (uniform in all four Rusinkiewicz angles, `neuenh.study.heldout`) "
            f"and measured on {s['test_samples']:,} other, independently drawn ones. Renders: {scene} under the "
            f"procedural studio environment, {s['size']}² pixels, {s['light_samples']} MIS light samples per pixel "
            "shared by truth and models; the metrics cover the sphere.", "",
            f"**The shipped model** (`{e['model'] if '/' in e['model'] else 'models/' + e['model']}`): "
            f"`{e['formula']}`, state `{e['state']}`, {e['weights']:,} weights."
            + (f" Its baselines with shared weights (`{s['baselines']}`) were trained as their bundles' provenance "
               "says, on the data and budget of the model shipped when they were trained." if s.get("baselines") else "")
            + (" Figures of earlier shipped models: [RESULTS_HISTORY.md](RESULTS_HISTORY.md)." if s.get("history") else ""),
            "",
            "## Held-out log-L1 (the paper's loss, lower is better)", "",
            f"The enhanced GGX is ahead of fitted plain GGX on **{self.enhanced_beats_ggx} of {len(materials)}** "
            f"materials; the median reduction is **{100 * self.median_reduction_vs_ggx:.1f} %**.", "",
            "| material | " + " | ".join(labels) + " | ours: lower than GGX by |",
            "|---|" + "---:|" * (len(names) + 1),
        ]
        for m in materials:
            r = {n: x.heldout_log_l1 for n, x in m.by_name().items()}
            best = min(r.values())
            cells = [f"**{r[n]:.4f}**" if r[n] == best else f"{r[n]:.4f}" for n in names]
            lines.append(f"| {m.material.replace('_rgb', '')} | " + " | ".join(cells)
                         + f" | {100 * (1 - r[ENHANCED] / r['ggx']):+.1f} % |")
        return [*lines, "", "![held-out log-L1 per material](img/results/heldout.png)", ""]

    def _renders(self, materials: list[MaterialResult]) -> list[str]:
        names = [m.name for m in self.models]
        lines = ["## Renders: SSIM (higher is better) and ΔE_ITP (lower is better)", "",
                 "ΔE_ITP is ITU-R BT.2124's, with linear 1.0 shown at 100 cd/m² (1 ≈ one just noticeable "
                 "difference), averaged over the sphere. The paper reports \"ΔE_ITP × 10³\" without stating its "
                 "luminance scale; our figures are not on that scale and are not multiplied.", "",
                 "| material | " + " | ".join(m.label for m in self.models) + " |", "|---|" + "---:|" * len(names)]
        for m in materials:
            r = m.by_name()
            lines.append(f"| {m.material.replace('_rgb', '')} | "
                         + " | ".join(f"{r[n].ssim:.3f} / {r[n].delta_e_itp:.2f}" for n in names) + " |")
        return [*lines, ""]

    def _speed(self) -> list[str]:
        lines = ["## Speed against error", "",
                 "Medians over the materials, measured in the same run. *Evaluations/s*: the fitted BRDF on "
                 f"{self.settings['eval_pairs']:,} direction pairs, one thread, best of 3. *Render rays/s*: (pixel, "
                 "light sample) pairs per second of the whole MIS render, so the BRDF's share of the time is diluted "
                 "by the light sampling (the paper's Mitsuba figure, enhanced/plain GGX = 0.63, is the same kind of "
                 "ratio). *Fit*: wall time of one material's fit (enhanced models: the analytical fit plus three "
                 "starts, `neuenh.fit`).", "",
                 "| model | evaluations/s | render rays/s | fit (s) | params per material | shared weights | "
                 "log-L1 | SSIM | ΔE_ITP |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for m in self.models:
            lines.append(f"| {m.label} | {_rate(m.evals_per_s)} | {_rate(m.rays_per_s)} | {m.fit_s:.1f} | "
                         f"{m.params} | {m.shared_weights:,} | {m.log_l1:.4f} | {m.ssim:.3f} | "
                         f"{m.delta_e:.2f} |")
        return [*lines, "", f"Enhanced / plain GGX: evaluation throughput ratio "
                f"**{self.eval_ratio_enhanced_to_ggx:.2f}**, render throughput ratio "
                f"**{self.render_ratio_enhanced_to_ggx:.2f}** (paper, Mitsuba: 0.63).", "",
                "![speed against error](img/results/speed_vs_error.png)", ""]


def _search(search: dict | None) -> list[str]:
    """The search's rounds, from the enhanced bundle's provenance (``examples/ship_reference.py``)."""
    if not search:
        return []
    lines = ["## The search", "", f"`{search.get('spec', 'examples/reference.yaml')}`: {search.get('summary', '')}",
             "", "| round | from | winner | val log-L1 | candidates |", "|---:|---|---|---:|---:|"]
    for r in search["rounds"]:
        win = next(x for x in r["candidates"] if x["state"] == r["winner_state"])
        lines.append(f"| {r['index']}{' (polish)' if r.get('kind') == 'polish' else ''} | `{r['parent_state']}` | "
                     f"`{r['winner_state']}` | {win['val_loss']:.5f} | {len(r['candidates'])} |")
    return [*lines, "", "![the search](img/results/search.png)", ""]


def _grids(materials: list[MaterialResult]) -> list[str]:
    lines = ["## Render grids", "",
             "Per material: the measured truth, the enhanced GGX, plain GGX and the best other model by held-out "
             "log-L1; below, relative luminance error maps on one scale per material.", ""]
    for m in materials:
        lines += [f"### {m.material}", "", f"![{m.material}](img/results/{m.material}.png)", ""]
    return lines
