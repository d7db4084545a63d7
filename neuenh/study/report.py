"""The study end to end (``neuenh report``): every contender fitted to each measured material in
worker processes, summarised, drawn and written (``RESULTS.md``, ``results.json``, figures)."""

from __future__ import annotations

import concurrent.futures
import json
import multiprocessing
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from ..files import atomic_write
from ..processes import die_with_parent
from .registry import (ANALYTICAL, BASELINES, EFFICIENCY_CONTENDERS, ENCODED, ENHANCED, ENHANCED_ADAPTIVE, OTHER_ENHANCED,
                       contender_infos)
from .summary import MaterialResult, StudySummary

__all__ = ["StudySettings", "build_contenders", "find_materials", "run_study"]


@dataclass(frozen=True)
class StudySettings:
    rgl: Path                  # folder of RGL .bsdf files
    model: str                 # the enhanced model: a shipped name or a bundle folder
    baselines: Path            # folder of the trained baseline bundles
    out: Path                  # where RESULTS.md, results.json and img/ go
    command: str               # the command that regenerates the study, for the document
    materials: tuple[str, ...] | None = None  # only these (file stems)
    fit_samples: int = 10_000
    test_samples: int = 10_000
    size: int = 96             # render size in pixels
    samples: int = 12          # light samples per pixel: the square of this
    scene: str = "ball"
    jobs: int = 2              # materials measured at once
    fit_epochs: int | None = None
    fit_starts: str = "analytical"
    eval_pairs: int = 200_000
    seed: int = 0
    efficiency: tuple[int, ...] = ()  # fit-set sizes of the data-efficiency curves (none: skipped)
    others: tuple[str, ...] = ()  # the shipped OTHER_ENHANCED models measured beside their originals

    def check(self) -> None:
        for name in ("fit_samples", "test_samples", "size", "samples", "jobs", "eval_pairs"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(self, name)}")
        if any(n < 1 for n in self.efficiency):
            raise ValueError(f"--efficiency sizes must be at least 1, got {list(self.efficiency)}")
        if self.fit_epochs is not None and self.fit_epochs < 1:
            raise ValueError(f"--fit-epochs must be at least 1, got {self.fit_epochs}")
        if not self.rgl.is_dir():
            raise FileNotFoundError(f"--rgl {self.rgl}: no such folder (the RGL .bsdf files, e.g. ../shared/data/rgl)")
        missing = [n for n, b in BASELINES.items() if not (b.bundle_dir(self.baselines) / "model.json").is_file()]
        if missing:
            raise ValueError(f"--baselines {self.baselines}: no trained {', '.join(missing)}; train them with "
                             "--train-baselines examples/reference.yaml")


def find_materials(folder: Path, names: tuple[str, ...] | None) -> list[Path]:
    paths = sorted(folder.glob("*.bsdf"))
    if names:
        by_stem = {p.stem: p for p in paths}
        unknown = [n for n in names if n not in by_stem]
        if unknown:
            raise ValueError(f"--materials: no {', '.join(unknown)} in {folder} (it has {', '.join(by_stem)})")
        paths = [by_stem[n] for n in names]
    if not paths:
        raise ValueError(f"--rgl {folder}: no .bsdf files")
    return paths


def run_study(settings: StudySettings) -> StudySummary:
    """Measures every material (``settings.jobs`` at a time) and writes the document, the JSON and
    the figures under ``settings.out``; returns the summary."""
    from ..checkpoint import Bundle
    from ..pretrained import bundle_path, load_model

    settings.check()
    start = time.perf_counter()
    paths = find_materials(settings.rgl, settings.materials)
    enhanced, _ = load_model(settings.model, "--model")  # fails early on a wrong name
    path = bundle_path(settings.model)
    bundle = Bundle.load(path) if path else None
    provenance = bundle.provenance if bundle else {}
    encoded = bundle is not None and bundle.encoder is not None
    materials = []
    fork = multiprocessing.get_context("fork")
    with concurrent.futures.ProcessPoolExecutor(settings.jobs, mp_context=fork, initializer=die_with_parent) as pool:
        for future in concurrent.futures.as_completed([pool.submit(_measure, settings, p) for p in paths]):
            m = future.result()
            materials.append(m)
            print(f"  {m.material}: " + ", ".join(f"{r.contender} {r.heldout_log_l1:.4f}" for r in m.results),
                  file=sys.stderr)
    materials.sort(key=lambda m: m.material)
    s = settings
    summary = StudySummary.of(
        materials, contender_infos(s.others, encoded), command=s.command, generated=time.strftime("%Y-%m-%d", time.gmtime()),
        wall_s=time.perf_counter() - start,
        settings={"fit_samples": s.fit_samples, "test_samples": s.test_samples, "size": s.size, "scene": s.scene,
                  "eval_pairs": s.eval_pairs, "fit_starts": s.fit_starts, "light_samples": s.samples ** 2,
                  "seed": s.seed, "jobs": s.jobs, "efficiency": list(s.efficiency),
                  "baselines": str(s.baselines), "history": (s.out / "RESULTS_HISTORY.md").exists()},
        enhanced={"model": s.model, "state": enhanced.state, "formula": enhanced.describe(),
                  "weights": enhanced.n_weights()})
    img = s.out / "img" / "results"
    img.mkdir(parents=True, exist_ok=True)
    _figures(img, summary, materials, provenance)
    _write(s.out / "results.json", json.dumps(summary.to_json(materials), indent=1) + "\n")
    _write(s.out / "RESULTS.md", summary.markdown(materials, provenance))
    print(f"wrote {s.out / 'RESULTS.md'}, {s.out / 'results.json'} and {img}/ "
          f"({len(materials)} materials, {time.perf_counter() - start:.0f} s)")
    return summary


def build_contenders(s: StudySettings, names: tuple[str, ...] | None = None) -> list:
    """The models of ``contender_infos()`` (only ``names`` when given), in its order, ready to be fitted
    per material; the enhanced model's contenders are fitted at their ``ContenderInfo.capacity``."""
    from ..checkpoint import Bundle
    from ..fit import FitOptions
    from ..models import get_model
    from ..pretrained import bundle_path, load_model
    from .contenders import EncodedContender, GraphContender, NBRDFContender
    from .nbrdf_fit import NBRDFConfig

    fit = FitOptions(epochs=s.fit_epochs, starts=s.fit_starts)
    path = bundle_path(s.model)
    encoder = Bundle.load(path).encoder if path else None
    out = []
    for info in contender_infos(s.others, encoder is not None):
        if names is not None and info.name not in names:
            continue
        if info.name in (ENHANCED, ENHANCED_ADAPTIVE):
            model, trained = load_model(s.model)
        elif info.name == ENCODED:
            out.append(EncodedContender(info.name, info.label, info.family, load_model(s.model)[0], encoder))
            continue
        elif info.name in OTHER_ENHANCED:
            model, trained = load_model(info.name)
        elif info.name in ANALYTICAL:
            model, trained = get_model(info.name), None
        elif info.name in BASELINES:
            bundle = Bundle.load(BASELINES[info.name].bundle_dir(s.baselines))
            model, trained = bundle.model, bundle.materials
        elif info.name == NBRDFContender.name:  # a network per material: no shared model
            out.append(NBRDFContender(NBRDFConfig(epochs=s.fit_epochs) if s.fit_epochs else NBRDFConfig()))
            continue
        else:
            raise ValueError(f"the registry names a contender nothing builds: {info.name!r}")
        out.append(GraphContender(info.name, info.label, info.family, model, trained,
                                  fit.replace(capacity=info.capacity),
                                  encoder if info.name in (ENHANCED, ENHANCED_ADAPTIVE) else None))
    return out


def _measure(s: StudySettings, path: Path) -> MaterialResult:
    """One material, in a worker process: every contender fitted, measured and rendered."""
    from ..data.measured import load_measured
    from ..fit.jit import set_fit_threads
    from .comparison import RenderSetup, compare_material

    set_fit_threads(1)  # as the fit processes of `neuenh fit --jobs`
    material, contenders = load_measured(path), build_contenders(s)
    c = compare_material(material, contenders, s.fit_samples, s.test_samples, seed=s.seed,
                         setup=RenderSetup(s.size, s.samples, s.seed, s.scene), eval_pairs=s.eval_pairs)
    curve = []
    if s.efficiency:
        from .efficiency import measure_curve

        curve = measure_curve(material, [x for x in contenders if x.name in EFFICIENCY_CONTENDERS], s.efficiency,
                              n_test=s.test_samples, seed=s.seed)
    return MaterialResult(c.material, c.n_fit, c.n_test, c.split, c.results, truth=c.truth.numpy(),
                          mask=c.mask.numpy(), images={k: v.numpy() for k, v in c.images.items()}, curve=curve)


def _figures(img: Path, summary: StudySummary, materials: list[MaterialResult], provenance: dict) -> None:
    from . import plots

    models = summary.models
    plots.speed_vs_error(img / "speed_vs_error.png", models)
    plots.heldout_bars(img / "heldout.png", [m.material for m in materials], models,
                       {x.name: [m.by_name()[x.name].heldout_log_l1 for m in materials] for x in models})
    if summary.settings.get("efficiency"):
        points = [p for m in materials for p in m.curve]
        plots.efficiency(img / "efficiency.png", points, {x.name: x.label for x in models})
    rounds = provenance.get("search", {}).get("rounds")
    if rounds:
        plots.search_path(img / "search.png", rounds)
    labels = {x.name: x.label for x in models}
    for m in materials:
        results = m.by_name()
        best = min((n for n in results if n not in (ENHANCED, "ggx")), key=lambda n: results[n].heldout_log_l1)
        columns = [(f"{labels[n]}\nlog-L1 {results[n].heldout_log_l1:.4f} · SSIM {results[n].ssim:.3f}", m.images[n])
                   for n in (ENHANCED, "ggx", best)]
        plots.render_grid(img / f"{m.material}.png", m.material, columns, m.truth, m.mask)


def _write(path: Path, text: str) -> None:
    atomic_write(path, text)
