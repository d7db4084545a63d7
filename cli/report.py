"""``neuenh report``: the evidence — every model fitted to the real RGL materials (never trained on),
measured on held-out samples and on renders, speed against error, the search, render grids.

    neuenh report [--rgl ../shared/data/rgl] [--model enhanced-ggx] [--baselines models/baselines]
                  [--out docs] [--fit-samples 10000] [--test-samples 10000] [--size 96] [--samples 12]
                  [--jobs 2] [--materials NAME ...] [--train-baselines SPEC [--work-dir runs/report]]

Writes ``OUT/RESULTS.md``, ``OUT/results.json`` and the figures in ``OUT/img/results/``: speed
against error with the Pareto front, the search path (from the model's provenance), held-out error
per material, and one render grid per material (truth, enhanced, plain GGX, the best other
baseline, error maps).

The models (``neuenh.study.registry``): the enhanced GGX (``--model``) fitted twice, at the latent
capacity (its latent code and analytical parameters) and adaptively (``neuenh fit --capacity auto``:
module-weight corrections chosen per material by cross-validation), the analytical GGX,
Cook-Torrance and Ward, NBRDF (a 6-21-21-3 network per material), and three baselines with shared
weights trained on the enhanced model's data with its budget (``orchestrator.baselines``): GGX plus a
residual MLP {32,64,64,16} and {32,64,128,128,64}, and the all-positions-neural GGX. They are read
from ``--baselines`` (the committed ``models/baselines``); ``--train-baselines examples/reference.yaml``
trains the missing ones first (tens of minutes on 2 cores), with the budget recorded in the enhanced
model's provenance. Every model is fitted per material to the same ``--fit-samples`` measurements and
measured on ``--test-samples`` others (independent draws, ``neuenh.study.heldout``).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from .outputs import output_folder


def configure(p: argparse.ArgumentParser) -> None:
    """``neuenh report``'s arguments, on the parser ``cli.main`` made for it (with its one-line help)."""
    p.description = __doc__
    p.formatter_class = argparse.RawDescriptionHelpFormatter
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
    p.add_argument("--efficiency", type=int, nargs="*", metavar="N", default=None,
                   help="also fit the enhanced model (both capacities), GGX, the small residual MLP and NBRDF on N "
                        "samples per material under both protocols (uniform; half near the mirror direction): the data-efficiency table "
                        "and plot (with no N: 100 300 1000 3000 10000)")
    # the defaults, to print the regenerating command with only the flags that differ
    p.set_defaults(run=run, defaults=vars(p.parse_args([])))


_NOT_IN_COMMAND = {"run", "defaults", "jobs", "work_dir", "train_baselines", "materials"}  # no effect on the results


def command(args) -> str:
    """``neuenh report`` with the flags that differ from the defaults and change the results."""
    flags = [f"--{key.replace('_', '-')} {getattr(args, key)}" for key, default in args.defaults.items()
             if key not in _NOT_IN_COMMAND | {"efficiency"} and getattr(args, key) != default]
    if args.efficiency is not None:
        flags.append(" ".join(["--efficiency", *map(str, args.efficiency)]))
    if args.materials:
        flags.append("--materials " + " ".join(args.materials))
    return " ".join(["neuenh report", *flags])


def _sizes(efficiency: list[int] | None) -> tuple[int, ...]:
    from neuenh.study.efficiency import SIZES

    if efficiency is None:
        return ()
    return tuple(efficiency) or SIZES


def run(args) -> int:
    from neuenh.study.registry import shipped_others
    from neuenh.study.report import StudySettings, run_study

    for flag, folder in (("--out", args.out), ("--work-dir", args.work_dir)):  # before hours of fitting
        output_folder(folder, flag)
    settings = StudySettings(
        rgl=args.rgl, model=args.model, baselines=args.baselines, out=args.out, command=command(args),
        materials=tuple(args.materials) if args.materials else None, fit_samples=args.fit_samples,
        test_samples=args.test_samples, size=args.size, samples=args.samples, scene=args.scene, jobs=args.jobs,
        fit_epochs=args.fit_epochs, fit_starts=args.fit_starts, eval_pairs=args.eval_pairs, seed=args.seed,
        efficiency=_sizes(args.efficiency), others=shipped_others())
    if args.train_baselines:
        from neuenh.checkpoint import Bundle
        from neuenh.pretrained import bundle_path, load_model
        from neuenh_service.orchestrator.baselines import train_missing_baselines

        load_model(args.model, "--model")  # fails early on a wrong name
        path = bundle_path(args.model)
        budget = Bundle.load(path).provenance.get("search", {}).get("budget") if path else None
        train_missing_baselines(args.train_baselines, budget, args.baselines, args.work_dir)
    run_study(settings)
    return 0
