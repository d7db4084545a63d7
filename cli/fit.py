"""``neuenh fit``: fit measured materials with an analytical model or a trained bundle.

    neuenh fit --model ggx measurements.npz [more.csv ...] [--capacity auto|latent|...] [--method fast|paper]
               [--kernel torch|jit] [--jobs N] [--json] [-o DIR] [--test held_out.npz [more_held_out.csv ...]]
               [--predictions out.npz]
    neuenh fit --model enhanced-ggx material.bsdf [more.binary ...] [--samples 3000] [--test-samples 1000]

Each table is one material (``.npz`` with ``wi``, ``wo``, ``f_r``, or CSV; see neuenh.data.table). The
module weights of a bundle stay frozen; only per-material parameters are optimised (neuenh.fit). A
model with modules fits each material at the capacity ``--capacity`` names: ``auto`` (default)
chooses per material, by validation on a held-out third of its own measurements, between the model
the search started from (``original``, e.g. plain GGX), the analytical model of the same graph
(``analytical``: modules back to their terms, the search's alternative terms kept), the latent code,
and per-material corrections of module weights (last layer, low rank), then fits the chosen one to
all of them (beyond 20,000 samples it chooses on a random 20,000); ``latent``, the latent code and
analytical parameters alone, takes about half the time (beyond 20,000 samples it fits a random
20,000) and fits less closely (docs/BENCHMARKS.md, "Stop 55: `auto` the users' default" and "The
adaptive fit of many samples chooses on 20,000 of them"). The capacity and
the material's parameter count are reported. ``-o DIR`` writes a bundle of the model with the fitted
materials, each with its capacity: ``neuenh export`` and ``neuenh render`` evaluate a material fitted
at the ``original`` or ``analytical`` capacity with that analytical model, and its row holds no latent
code for later fits and encoders.

A measurement may also be a measured file (an RGL ``.bsdf``, a MERL ``.binary``, told by content):
``--samples`` pairs are drawn from it (default 3,000), ``--near-mirror`` of them with the half vector
near the normal (default 0.5, where a glossy material's highlight is), seeded by ``--seed``; and
``--test-samples N`` draws N more, independently, to measure each such material held out (the
protocol of ``neuenh.study.heldout.draw_fit_test``). Tables and measured files fit side by side;
held out, tables take ``--test`` and measured files ``--test-samples``, one kind per fit.

``--test`` takes one held-out table per fitted table, in the same order: the i-th held-out table is
measured with the parameters fitted to the i-th table, whatever its file name (the material keeps
the fitted table's name). The counts must match and no held-out table may be a fitted one. Each
material then gets its held-out log-L1 (``heldout_log_l1``, the training loss on samples not
fitted; see neuenh.study.heldout). Put ``--test`` after the measurements (it takes every table that
follows it). ``--predictions OUT.npz`` (needs ``--test`` or ``--test-samples``) writes, atomically,
the fitted model's f_r at the held-out directions: arrays ``wi``, ``wo``, ``f_r`` (n, 3), ``material``
(n,) indices into ``material_names``; with a single material ``neuenh.data.table.read_table`` reads
it as a table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from neuenh.capacities import CAPACITY_CHOICES, CAPACITY_HELP, USER_CAPACITY
from neuenh.models import available_models
from neuenh.pretrained import shipped_models

from .draws import add_draw_arguments, check_draw_arguments, draw, is_measured
from .outputs import output_folder
from .progress import StepBar
from .tables import fit_report



def configure(p: argparse.ArgumentParser) -> None:
    """``neuenh fit``'s arguments, on the parser ``cli.main`` made for it (with its one-line help)."""
    p.description = __doc__
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("tables", nargs="+", metavar="MEASUREMENTS",
                   help="one table (.npz or CSV) or measured file (RGL .bsdf, MERL .binary) per material")
    p.add_argument("--model", default="ggx",
                   help=f"an analytical model ({', '.join(available_models())}), a shipped model "
                        f"({', '.join(shipped_models()) or 'none'}) or a bundle directory")
    p.add_argument("--starts", choices=("analytical", "paper"), default="analytical",
                   help="an enhanced model's starting points: analytical (default) fits the analytical "
                        "model first and starts from it and from the bundle's best-fitting training codes; "
                        "paper: the range means and latent 0.5")
    p.add_argument("--method", choices=("fast", "paper"), default="fast",
                   help="fast (default): a plain model by L-BFGS, a model with modules at --capacity; paper: "
                        "RMSProp lr 1e-3, 1000 epochs, latent capacity")
    p.add_argument("--capacity", default=USER_CAPACITY, metavar="{" + ",".join(CAPACITY_CHOICES) + "}",
                   help=CAPACITY_HELP)
    p.add_argument("--kernel", choices=("torch", "jit"), default=None, help=(
        "the fit's kernel: torch, or jit: each step one compiled Dr.Jit kernel (neuenh[export] and libLLVM 17+), "
        "a latent fit 2-3x faster, the adaptive fit's analytical and latent stages too; the same objective to "
        "float32 rounding, which moves some materials' end points as a fit's seed does. Default: jit for "
        "--capacity latent fits of at least 200,000 measurement-epochs where Dr.Jit runs, torch for smaller ones "
        "and for the other capacities (docs/BENCHMARKS.md, 'Stop 68'). A model's first jit fit on a machine "
        "compiles (the shipped model: ~15 s), later ones read Dr.Jit's disk cache"))
    p.add_argument("--epochs", type=int, default=None,
                   help="epochs of the first-order fits (Adam, RMSProp; default each protocol's own); a plain "
                        "model's L-BFGS iterations per phase unless --lbfgs-iterations")
    p.add_argument("--lbfgs-iterations", type=int, default=None,
                   help="a plain model's L-BFGS iterations per surrogate phase (default 300)")
    p.add_argument("--threads", type=int, default=None, help=(
        "torch CPU threads, and Dr.Jit's (default: all); on a machine busy with other work 1 "
        "can be several times faster, since idle threads wait by spinning (docs/BENCHMARKS.md, 'Fit threads')"))
    p.add_argument("--jobs", type=int, default=1, metavar="N", help=(
        "fit the materials in N processes of one thread each (default 1: here). Each process takes a few "
        "seconds to start, so it pays for many materials: enhanced-ggx, 8 of 3,000 samples, 1.5-1.7x "
        "faster with 2. A material's result is its share's fit alone: N changes the rounding, not the method"))
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("-o", "--output", type=Path, help="write a bundle with the fitted materials here")
    p.add_argument("--test", nargs="+", metavar="TABLE", type=Path,
                   help="held-out tables, one per fitted table in the same order: adds each material's "
                        "held-out log-L1")
    p.add_argument("--predictions", type=Path, metavar="OUT.npz",
                   help="write the fitted model's f_r at the held-out directions (needs --test or --test-samples)")
    add_draw_arguments(p)
    p.add_argument("--test-samples", type=int, default=None, metavar="N",
                   help="held-out pairs drawn independently from each measured file: adds its held-out log-L1")
    p.set_defaults(run=run)


def run(args) -> int:
    from neuenh.checkpoint import Bundle
    from neuenh.fit import FitOptions, fit_in_processes
    from neuenh.fit.jit import set_fit_threads
    from neuenh.pretrained import load_for_fitting
    from neuenh.study.heldout import heldout_log_l1, predict_f_r, write_predictions

    if args.threads:
        set_fit_threads(args.threads)
    if args.jobs < 1:
        raise ValueError(f"--jobs must be at least 1, got {args.jobs}")
    drawn = _check_measurement_args(args)
    _check_heldout_args(args)
    if args.output:
        if args.output.suffix == ".json" and not args.output.exists():  # the fit report is JSON, the bundle a folder
            raise ValueError(f"-o {args.output}: -o writes a bundle, a folder (model.json, weights, materials); the fit "
                             f"report as JSON is --json > {args.output}")
        output_folder(args.output)
    options = FitOptions(method=args.method, capacity=args.capacity, epochs=args.epochs,
                         lbfgs_iterations=args.lbfgs_iterations, starts=args.starts, kernel=args.kernel)
    model, trained, encoder = load_for_fitting(args.model, "--model")
    samples, test = _measurements(args, drawn)
    if len(set(samples.names)) != len(samples.names):
        raise ValueError(f"two measurements share a material name: {samples.names}")
    protocol = options.protocol_for(model)
    bar = StepBar(sys.stderr, quiet_unless_live=True)  # a person at a terminal sees the fit run; a pipe sees nothing
    what = f"materials fitted: {args.model}, {protocol.name} fit, {len(samples):,} samples"
    bar(what, 0, len(samples.names))
    try:
        result = fit_in_processes(model, samples, protocol, args.jobs, trained=trained, encoder=encoder,
                                  progress=lambda done, total: bar(what, done, total))
    finally:
        bar.done()  # an error's line starts on a line of its own
    report = result.report(model, samples)
    metrics: dict = {"fit_loss": result.losses}
    if test is not None:
        heldout = heldout_log_l1(model, result, test)
        counts = test.counts().tolist()
        for entry, loss, count, path in zip(report["materials"], heldout, counts, args.test or args.tables):
            entry.update(heldout_log_l1=loss, heldout_samples=count, heldout_table=str(path))
        metrics["heldout_log_l1"] = heldout
    if args.predictions:
        write_predictions(args.predictions, test, predict_f_r(model, result, test))
        report["predictions"] = str(args.predictions)
    if args.output:
        provenance = {"fitted_from": [str(t) for t in args.tables], "fit_protocol": result.protocol,
                      "fitted_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
        if any(drawn):
            provenance["drawn"] = {"samples": args.samples, "near_mirror": args.near_mirror, "seed": args.seed,
                                   "test_samples": args.test_samples}
        if args.test:
            provenance["heldout_tables"] = [str(t) for t in args.test]
        Bundle(model, result.materials, provenance=provenance, metrics=metrics, encoder=encoder).save(args.output)
        report["bundle"] = str(args.output)
    print(json.dumps(report, indent=2) if args.json else fit_report(report))
    return 0


def _measurements(args, drawn: list[bool]):
    """The fit's samples, a material per MEASUREMENT (a table's rows, or a measured file's draw: ``drawn``
    says which), and the held-out samples (``--test`` tables, or ``--test-samples`` independent draws), or
    None."""
    from neuenh.data.samples import Samples
    from neuenh.data.table import read_table

    parts = [draw(t, args, args.test_samples) if d else (read_table(t), None) for t, d in zip(args.tables, drawn)]
    samples = Samples.concat([fit for fit, _ in parts])
    if args.test:
        return samples, Samples.concat([read_table(t, name=samples.names[i]) for i, t in enumerate(args.test)])
    return samples, Samples.concat([test for _, test in parts]) if args.test_samples else None


def _check_measurement_args(args) -> list[bool]:
    """Usage errors of the measurements and their draws, found before any fitting; per measurement
    whether it is a measured file, drawn (else a table, with its rows). Held out, tables take ``--test``
    tables and measured files ``--test-samples`` draws: one kind of measurement per fit then."""
    drawn = [is_measured(t) for t in args.tables]
    if args.test and any(drawn):
        raise ValueError("--test takes a held-out table per fitted table; measured files (RGL, MERL) are measured "
                         "held out with --test-samples N (an independent draw)")
    if args.test_samples is not None and not all(drawn):
        raise ValueError("--test-samples draws from measured files (RGL, MERL); a table's held-out rows are a "
                         "--test table")
    check_draw_arguments(args, args.test_samples)
    return drawn


def _check_heldout_args(args) -> None:
    """Usage errors of ``--test``/``--predictions``, found before any fitting."""
    if args.predictions and not (args.test or args.test_samples):
        raise ValueError("--predictions needs --test or --test-samples: predictions are written at the held-out "
                         "directions")
    if not args.test:
        return
    if len(args.test) != len(args.tables):
        raise ValueError(f"--test takes one held-out table per fitted table, in the same order: "
                         f"got {len(args.test)} for {len(args.tables)}")
    fitted = {Path(t).resolve() for t in args.tables}
    for t in args.test:
        if Path(t).resolve() in fitted:
            raise ValueError(f"--test {t} is also a fitted table; held-out samples must not be fitted")
    if args.predictions:
        parent = args.predictions.resolve().parent
        if not parent.is_dir():
            raise ValueError(f"--predictions {args.predictions}: directory {parent} does not exist")
        if args.predictions.is_dir():
            raise ValueError(f"--predictions {args.predictions} is a directory")
