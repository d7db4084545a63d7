"""``neuenh report``: the evidence — every model fitted to the real RGL materials (never trained on),
measured on held-out samples and on renders, speed against error, the search, render grids.

    neuenh report [--rgl ../shared/data/rgl] [--model enhanced-ggx] [--baselines models/baselines]
                  [--out docs] [--fit-samples 10000] [--test-samples 10000] [--size 96] [--samples 12]
                  [--jobs 2] [--materials NAME ...] [--train-baselines SPEC [--work-dir runs/report]]

Writes ``OUT/RESULTS.md``, ``OUT/results.json`` and the figures in ``OUT/img/results/``: speed
against error with the Pareto front, the search path (from the model's provenance), held-out error
per material, and one render grid per material (truth, enhanced, plain GGX, the best other
baseline, error maps).

The models: the enhanced GGX (``--model``), the analytical GGX, Cook-Torrance and Ward, NBRDF (a
6-21-21-3 network per material), and three baselines with shared weights trained on the enhanced
model's data with its budget (``orchestrator.baselines``): GGX plus a residual MLP {32,64,64,16}
and {32,64,128,128,64}, and the all-positions-neural GGX. They are read from ``--baselines`` (the
committed ``models/baselines``); ``--train-baselines examples/reference.yaml`` trains the missing
ones first (tens of minutes on 2 cores), with the budget recorded in the enhanced model's
provenance. Every model is fitted per material to the same ``--fit-samples`` measurements and
measured on ``--test-samples`` others (independent draws, ``neuenh.evaluate``).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import math
import multiprocessing
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from neuenh.models.ggx_residual import RESIDUAL_STATE

# name -> (label, family, model, state, hidden widths or None for the spec's)
BASELINES = {
    "residual-1x": ("GGX + residual {32,64,64,16}", "residual", "ggx_residual", RESIDUAL_STATE, (32, 64, 64, 16)),
    "residual-5x": ("GGX + residual {32,64,128,128,64}", "residual", "ggx_residual", RESIDUAL_STATE,
                    (32, 64, 128, 128, 64)),
    "all-neural": ("all positions neural", "neural", "ggx", "1" * 11, None),
}
ANALYTICAL = {"ggx": "GGX", "cook_torrance": "Cook-Torrance", "ward": "Ward"}
ENHANCED = "enhanced"


def add_parser(commands) -> None:
    p = commands.add_parser("report", help="measure every model on the RGL materials; write RESULTS.md and plots",
                            description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rgl", type=Path, default=Path("../shared/data/rgl"), help="folder of RGL .bsdf files")
    p.add_argument("--model", default="enhanced-ggx", help="the enhanced model: a shipped name or a bundle folder")
    p.add_argument("--baselines", type=Path, default=Path("models/baselines"),
                   help="folder of the trained baseline bundles (residual-1x, residual-5x, all-neural)")
    p.add_argument("--train-baselines", type=Path, metavar="SPEC",
                   help="train the missing baselines on this job spec's data first")
    p.add_argument("--work-dir", type=Path, default=Path("runs/report"), help="dataset cache for --train-baselines")
    p.add_argument("--out", type=Path, default=Path("docs"), help="where RESULTS.md, results.json and img/ go")
    p.add_argument("--materials", nargs="+", metavar="NAME", help="only these materials (file stems)")
    p.add_argument("--fit-samples", type=int, default=10_000)
    p.add_argument("--test-samples", type=int, default=10_000)
    p.add_argument("--size", type=int, default=96, help="render size in pixels")
    p.add_argument("--samples", type=int, default=12, help="light samples per pixel: the square of this")
    p.add_argument("--scene", choices=("ball", "sphere"), default="ball",
                   help="renders: the sphere on a ground plane with shadows (default) or alone")
    p.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1), help="materials measured at once")
    p.add_argument("--fit-epochs", type=int, default=None,
                   help="epochs of every per-material fit (default: each method's, 300)")
    p.add_argument("--fit-starts", choices=("analytical", "paper"), default="analytical",
                   help="starting points of the models with modules (neuenh.fit): several, or the paper's alone")
    p.add_argument("--eval-pairs", type=int, default=200_000, help="direction pairs timing each BRDF's evaluation")
    p.add_argument("--seed", type=int, default=0)
    # the defaults, to print the regenerating command with only the flags that differ
    p.set_defaults(run=run, defaults=vars(p.parse_args([])))


def run(args) -> int:
    _check_args(args)
    start = time.perf_counter()
    materials = _materials(args.rgl, args.materials)
    from neuenh.pretrained import load_model

    enhanced, _ = load_model(args.model, "--model")  # fails early on a wrong name
    provenance = _provenance(args.model)
    if args.train_baselines:
        _train_missing(args, provenance)
    missing = [n for n in BASELINES if not (args.baselines / n / "model.json").is_file()]
    if missing:
        raise ValueError(f"--baselines {args.baselines}: no trained {', '.join(missing)}; train them with "
                         "--train-baselines examples/reference.yaml")
    img = args.out / "img" / "results"
    img.mkdir(parents=True, exist_ok=True)
    contenders = _contender_info(args)
    comparisons = []
    context = multiprocessing.get_context("fork")
    with concurrent.futures.ProcessPoolExecutor(max_workers=args.jobs, mp_context=context) as pool:
        futures = {pool.submit(_measure, vars(args), str(path)): path for path in materials}
        for future in concurrent.futures.as_completed(futures):
            result = future.result()
            comparisons.append(result)
            print(f"  {result['material']}: " + ", ".join(
                f"{r['contender']} {r['heldout_log_l1']:.4f}" for r in result["results"]), file=sys.stderr)
    comparisons.sort(key=lambda c: c["material"])
    summary = _summarise(args, contenders, comparisons, provenance, enhanced, time.perf_counter() - start)
    _figures(img, summary, comparisons, provenance)
    for c in comparisons:
        c.pop("images"), c.pop("truth"), c.pop("mask")
    _write(args.out / "results.json", json.dumps({**summary, "materials": comparisons}, indent=1) + "\n")
    _write(args.out / "RESULTS.md", markdown(summary, comparisons, provenance))
    print(f"wrote {args.out / 'RESULTS.md'}, {args.out / 'results.json'} and {img}/ "
          f"({len(materials)} materials, {time.perf_counter() - start:.0f} s)")
    return 0


# -- inputs ------------------------------------------------------------------------------------------
def _check_args(args) -> None:
    for flag in ("fit_samples", "test_samples", "size", "samples", "jobs", "eval_pairs"):
        if getattr(args, flag) < 1:
            raise ValueError(f"--{flag.replace('_', '-')} must be at least 1, got {getattr(args, flag)}")
    if args.fit_epochs is not None and args.fit_epochs < 1:
        raise ValueError(f"--fit-epochs must be at least 1, got {args.fit_epochs}")
    if not args.rgl.is_dir():
        raise FileNotFoundError(f"--rgl {args.rgl}: no such folder (the RGL .bsdf files, e.g. ../shared/data/rgl)")


def _materials(folder: Path, names: list[str] | None) -> list[Path]:
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


def _provenance(spec: str) -> dict:
    from neuenh.checkpoint import Bundle
    from neuenh.pretrained import bundle_path

    path = bundle_path(spec)
    return Bundle.load(path).provenance if path else {}


def _train_missing(args, provenance: dict) -> None:
    from neuenh.modules import ModuleConfig
    from orchestrator.baselines import train_like_search
    from orchestrator.dataset import prepare_dataset
    from orchestrator.spec import load_spec
    from storage import LocalArtifactStore

    budget = provenance.get("search", {}).get("budget")
    if not budget:
        raise ValueError(f"--model {args.model}: its provenance records no search budget to train baselines with")
    spec = load_spec(args.train_baselines)
    data = None
    for name, (label, _, model, state, hidden) in BASELINES.items():
        target = args.baselines / name
        if (target / "model.json").is_file():
            continue
        if data is None:
            data, _ = prepare_dataset(spec, LocalArtifactStore(args.work_dir / "artifacts"))
        print(f"training {name} ({label}) for {sum(budget)} epochs ...", file=sys.stderr)
        config = ModuleConfig(choices=(tuple(hidden),)) if hidden else spec.module.config()
        start = time.perf_counter()
        result = train_like_search(spec, data, tuple(budget), model, state, config)
        result.bundle.provenance = {"baseline": name, "label": label, "spec": str(args.train_baselines),
                                    "budget": list(budget), "train_s": round(time.perf_counter() - start, 1)}
        result.bundle.save(target)
        print(f"  {name}: val log-L1 {result.val_loss:.5f}", file=sys.stderr)


def _contender_info(args) -> list[dict]:
    out = [{"name": ENHANCED, "label": "Enhanced GGX (ours)", "family": "enhanced"}]
    out += [{"name": n, "label": label, "family": "analytical"} for n, label in ANALYTICAL.items()]
    out += [{"name": n, "label": b[0], "family": b[1]} for n, b in BASELINES.items()]
    out.append({"name": "nbrdf", "label": "NBRDF (per material)", "family": "neural"})
    return out


def _contenders(args: dict) -> list:
    from neuenh.checkpoint import Bundle
    from neuenh.contenders import GraphContender, NBRDFContender
    from neuenh.fit import FitConfig
    from neuenh.nbrdf_fit import NBRDFConfig
    from neuenh.models import get_model
    from neuenh.pretrained import load_model

    fit = FitConfig(epochs=args["fit_epochs"], starts=args["fit_starts"])
    enhanced, trained = load_model(args["model"])
    out = [GraphContender(ENHANCED, "Enhanced GGX (ours)", "enhanced", enhanced, trained, fit)]
    out += [GraphContender(n, label, "analytical", get_model(n), config=fit) for n, label in ANALYTICAL.items()]
    for name, (label, family, *_rest) in BASELINES.items():
        bundle = Bundle.load(Path(args["baselines"]) / name)
        out.append(GraphContender(name, label, family, bundle.model, bundle.materials, fit))
    out.append(NBRDFContender(NBRDFConfig(epochs=args["fit_epochs"]) if args["fit_epochs"] else NBRDFConfig()))
    return out


def _measure(args: dict, path: str) -> dict:
    """One material, in a worker process: every contender fitted, measured and rendered."""
    import torch

    from neuenh.comparison import RenderSetup, compare_material
    from neuenh.data.measured import load_measured

    torch.set_num_threads(1)
    material = load_measured(path)
    comparison = compare_material(material, _contenders(args), args["fit_samples"], args["test_samples"],
                                  seed=args["seed"], setup=RenderSetup(args["size"], args["samples"], args["seed"], args["scene"]),
                                  eval_pairs=args["eval_pairs"])
    return {"material": comparison.material, "n_fit": comparison.n_fit, "n_test": comparison.n_test,
            "split": comparison.split, "results": [r.row() for r in comparison.results],
            "truth": comparison.truth.numpy(), "mask": comparison.mask.numpy(),
            "images": {k: v.numpy() for k, v in comparison.images.items()}}


# -- summary ---------------------------------------------------------------------------------------
def _summarise(args, contenders: list[dict], comparisons: list[dict], provenance: dict, enhanced, wall_s) -> dict:
    models = []
    for c in contenders:
        rows = [next(r for r in m["results"] if r["contender"] == c["name"]) for m in comparisons]
        models.append({**c,
                       "log_l1": statistics.median(r["heldout_log_l1"] for r in rows),
                       "mean_log_l1": statistics.fmean(r["heldout_log_l1"] for r in rows),
                       "ssim": statistics.median(r["ssim"] for r in rows),
                       "delta_e": statistics.median(r["delta_e_itp"] for r in rows),
                       "evals_per_s": statistics.median(r["evals_per_s"] for r in rows),
                       "rays_per_s": sum(r["rays"] for r in rows) / sum(r["render_s"] for r in rows),
                       "fit_s": statistics.median(r["fit_s"] for r in rows),
                       "params_per_material": rows[0]["params_per_material"],
                       "shared_weights": rows[0]["shared_weights"]})
    by_name = {m["name"]: m for m in models}
    reductions = []
    for m in comparisons:
        r = {x["contender"]: x for x in m["results"]}
        reductions.append(1.0 - r[ENHANCED]["heldout_log_l1"] / r["ggx"]["heldout_log_l1"])
    return {
        "command": " ".join(["neuenh report", *_command_flags(args)]),
        "generated": time.strftime("%Y-%m-%d", time.gmtime()),
        "wall_s": round(wall_s, 1),
        "settings": {"fit_samples": args.fit_samples, "test_samples": args.test_samples, "size": args.size,
                     "scene": args.scene, "eval_pairs": args.eval_pairs, "fit_starts": args.fit_starts,
                     "light_samples": args.samples ** 2, "seed": args.seed, "jobs": args.jobs},
        "enhanced": {"model": args.model, "state": enhanced.state, "formula": enhanced.describe(),
                     "weights": enhanced.n_weights()},
        "models": models,
        "enhanced_beats_ggx": sum(x > 0 for x in reductions),
        "median_reduction_vs_ggx": statistics.median(reductions),
        "render_ratio_enhanced_to_ggx": by_name[ENHANCED]["rays_per_s"] / by_name["ggx"]["rays_per_s"],
        "eval_ratio_enhanced_to_ggx": by_name[ENHANCED]["evals_per_s"] / by_name["ggx"]["evals_per_s"],
    }


_NOT_IN_COMMAND = {"run", "defaults", "jobs", "work_dir", "train_baselines", "materials"}  # no effect on the results


def _command_flags(args) -> list[str]:
    flags = [f"--{key.replace('_', '-')} {getattr(args, key)}" for key, default in args.defaults.items()
             if key not in _NOT_IN_COMMAND and getattr(args, key) != default]
    if args.materials:
        flags.append("--materials " + " ".join(args.materials))
    return flags


def _figures(img: Path, summary: dict, comparisons: list[dict], provenance: dict) -> None:
    from . import report_plots as plots

    models = summary["models"]
    plots.speed_vs_error(img / "speed_vs_error.png", models)
    plots.heldout_bars(img / "heldout.png", [c["material"] for c in comparisons], models,
                       {m["name"]: [next(r["heldout_log_l1"] for r in c["results"] if r["contender"] == m["name"])
                                    for c in comparisons] for m in models})
    rounds = provenance.get("search", {}).get("rounds")
    if rounds:
        plots.search_path(img / "search.png", rounds)
    labels = {m["name"]: m["label"] for m in models}
    for c in comparisons:
        results = {r["contender"]: r for r in c["results"]}
        best = _best_other(results)
        columns = [(f"{labels[n]}\nlog-L1 {results[n]['heldout_log_l1']:.4f} · SSIM {results[n]['ssim']:.3f}",
                    c["images"][n]) for n in (ENHANCED, "ggx", best)]
        plots.render_grid(img / f"{c['material']}.png", c["material"], columns, c["truth"], c["mask"])


def _best_other(results: dict) -> str:
    """The best baseline other than the enhanced model and plain GGX, by held-out log-L1."""
    return min((n for n in results if n not in (ENHANCED, "ggx")), key=lambda n: results[n]["heldout_log_l1"])


def _write(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


# -- the document ----------------------------------------------------------------------------------
def _fmt_rate(x: float) -> str:
    return f"{x / 1e6:.2f} M" if x >= 1e6 else f"{x / 1e3:.0f} k"


def markdown(summary: dict, comparisons: list[dict], provenance: dict) -> str:
    models = summary["models"]
    names = [m["name"] for m in models]
    labels = {m["name"]: m["label"] for m in models}
    s, e = summary["settings"], summary["enhanced"]
    lines = [
        "# Results: the enhanced GGX on real measured materials",
        "",
        f"Regenerate everything on this page (tables, figures, `results.json`) with `{summary['command']}` "
        f"({summary['wall_s'] / 60:.0f} min on this 2-core machine, {s['jobs']} materials at a time; generated "
        f"{summary['generated']}).",
        "",
        f"**Materials:** the {len(comparisons)} EPFL RGL materials of `../shared/data/rgl` (Dupuy & Jakob 2018), "
        "never seen in training. **Protocol:** every model is fitted per material to the same "
        f"{s['fit_samples']:,} measurements (uniform in all four Rusinkiewicz angles, `neuenh.evaluate`) and "
        f"measured on {s['test_samples']:,} other, independently drawn ones. Renders: "
        + ("a sphere on a grey ground plane (shadows both ways)" if s.get("scene", "ball") == "ball" else "a sphere")
        + f" under the procedural studio environment, {s['size']}² pixels, {s['light_samples']} MIS light "
        "samples per pixel shared by truth and models; the metrics cover the sphere.",
        "",
        f"**The shipped model** (`{e['model'] if '/' in e['model'] else 'models/' + e['model']}`): `{e['formula']}`, state `{e['state']}`, "
        f"{e['weights']:,} weights.",
        "",
        "## Held-out log-L1 (the paper's loss, lower is better)",
        "",
        f"The enhanced GGX is ahead of fitted plain GGX on **{summary['enhanced_beats_ggx']} of {len(comparisons)}** "
        f"materials; the median reduction is **{100 * summary['median_reduction_vs_ggx']:.1f} %**.",
        "",
        "| material | " + " | ".join(labels[n] for n in names) + " | ours: lower than GGX by |",
        "|---|" + "---:|" * (len(names) + 1),
    ]
    for c in comparisons:
        r = {x["contender"]: x["heldout_log_l1"] for x in c["results"]}
        best = min(r.values())
        cells = [f"**{r[n]:.4f}**" if r[n] == best else f"{r[n]:.4f}" for n in names]
        lines.append(f"| {c['material'].replace('_rgb', '')} | " + " | ".join(cells)
                     + f" | {100 * (1 - r[ENHANCED] / r['ggx']):+.1f} % |")
    lines += ["", "![held-out log-L1 per material](img/results/heldout.png)", "",
              "## Renders: SSIM (higher is better) and ΔE_ITP (lower is better)", "",
              "ΔE_ITP is ITU-R BT.2124's, with linear 1.0 shown at 100 cd/m² (1 ≈ one just noticeable "
              "difference), averaged over the sphere. The paper reports \"ΔE_ITP × 10³\" without stating its "
              "luminance scale; our figures are not on that scale and are not multiplied.", "",
              "| material | " + " | ".join(labels[n] for n in names) + " |",
              "|---|" + "---:|" * len(names)]
    for c in comparisons:
        r = {x["contender"]: x for x in c["results"]}
        lines.append(f"| {c['material'].replace('_rgb', '')} | "
                     + " | ".join(f"{r[n]['ssim']:.3f} / {r[n]['delta_e_itp']:.2f}" for n in names) + " |")
    lines += ["", "## Speed against error", "",
              "Medians over the materials, measured in the same run. *Evaluations/s*: the fitted BRDF on "
              f"{s['eval_pairs']:,} direction pairs, one thread, best of 3. *Render rays/s*: (pixel, light sample) "
              "pairs per "
              "second of the whole MIS render, so the BRDF's share of the time is diluted by the light sampling "
              "(the paper's Mitsuba figure, enhanced/plain GGX = 0.63, is the same kind of ratio). *Fit*: wall time "
              "of one material's fit (enhanced models: the analytical fit plus three starts, `neuenh.fit`).", "",
              "| model | evaluations/s | render rays/s | fit (s) | params per material | shared weights | "
              "log-L1 | SSIM | ΔE_ITP |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for m in models:
        lines.append(f"| {m['label']} | {_fmt_rate(m['evals_per_s'])} | {_fmt_rate(m['rays_per_s'])} | "
                     f"{m['fit_s']:.1f} | {m['params_per_material']} | {m['shared_weights']:,} | {m['log_l1']:.4f} | "
                     f"{m['ssim']:.3f} | {m['delta_e']:.2f} |")
    lines += ["", f"Enhanced / plain GGX: evaluation throughput ratio **{summary['eval_ratio_enhanced_to_ggx']:.2f}**, "
              f"render throughput ratio **{summary['render_ratio_enhanced_to_ggx']:.2f}** (paper, Mitsuba: 0.63).", "",
              "![speed against error](img/results/speed_vs_error.png)", ""]
    search = provenance.get("search")
    if search:
        lines += ["## The search", "",
                  f"`{search.get('spec', 'examples/reference.yaml')}`: {search.get('summary', '')}", "",
                  "| round | from | winner | val log-L1 | candidates |", "|---:|---|---|---:|---:|"]
        for r in search["rounds"]:
            win = next(x for x in r["candidates"] if x["state"] == r["winner_state"])
            lines.append(f"| {r['index']}{' (polish)' if r.get('polish') else ''} | `{r['parent_state']}` | "
                         f"`{r['winner_state']}` | {win['val_loss']:.5f} | {len(r['candidates'])} |")
        lines += ["", "![the search](img/results/search.png)", ""]
    lines += ["## Render grids", "",
              "Per material: the measured truth, the enhanced GGX, plain GGX and the best other model by held-out "
              "log-L1; below, relative luminance error maps on one scale per material.", ""]
    for c in comparisons:
        lines += [f"### {c['material']}", "", f"![{c['material']}](img/results/{c['material']}.png)", ""]
    return "\n".join(lines)
