"""``neuenh fit``: fit measured materials with an analytical model or a trained bundle.

    neuenh fit --model ggx measurements.npz [more.csv ...] [--method fast|paper] [--json] [-o DIR]

Each table is one material (``.npz`` with ``wi``, ``wo``, ``f_r``, or CSV; see neuenh.data.table). The
module weights of a bundle stay frozen; only per-material parameters are optimised. ``-o DIR``
writes a bundle of the model with the fitted materials.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from neuenh.checkpoint import Bundle
from neuenh.data.samples import Samples
from neuenh.data.table import read_table
from neuenh.fit import FitConfig, fit_materials
from neuenh.graph import BRDFModel
from neuenh.models import available_models, get_model


def add_parser(commands) -> None:
    p = commands.add_parser("fit", help="fit measured materials with a model (module weights frozen)",
                            description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("tables", nargs="+", metavar="MEASUREMENTS", help="one table (.npz or CSV) per material")
    p.add_argument("--model", default="ggx",
                   help=f"an analytical model ({', '.join(available_models())}) or a bundle directory")
    p.add_argument("--method", choices=("fast", "paper"), default="fast",
                   help="fast (default): Adam with cosine decay; paper: RMSProp lr 1e-3, 1000 epochs")
    p.add_argument("--epochs", type=int, default=None, help="override the method's epoch count")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: all)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("-o", "--output", type=Path, help="write a bundle with the fitted materials here")
    p.set_defaults(run=run)


def load_model(spec: str) -> BRDFModel:
    """A model name from the registry, or a bundle directory."""
    path = Path(spec)
    if path.is_dir():
        return Bundle.load(path).model
    if spec in available_models():
        return get_model(spec)
    raise ValueError(f"--model {spec!r} is neither a model ({', '.join(available_models())}) "
                     "nor a bundle directory")


def run(args) -> int:
    if args.threads:
        torch.set_num_threads(args.threads)
    model = load_model(args.model)
    samples = Samples.concat([read_table(t) for t in args.tables])
    if len(set(samples.names)) != len(samples.names):
        raise ValueError(f"two tables share a material name: {samples.names}")
    result = fit_materials(model, samples, FitConfig(method=args.method, epochs=args.epochs))
    if args.output:
        Bundle(model, result.materials, provenance={"fitted_from": [str(t) for t in args.tables],
                                                    "fit_method": args.method,
                                                    "fitted_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())},
               metrics={"fit_loss": result.losses}).save(args.output)
    report = result.report(model, args.method, samples)
    if args.output:
        report["bundle"] = str(args.output)
    print(json.dumps(report, indent=2) if args.json else _table(report))
    return 0


def _table(report: dict) -> str:
    lines = [f"{report['model']} (state {report['state']}), {report['method']} fit, "
             f"{report['epochs']} epochs in {report['wall_s']:.1f} s"]
    for m in report["materials"]:
        p = m["params"]
        scalars = "  ".join(f"{k}={_fmt(v)}" for k, v in p.items() if k != "latent")
        lines.append(f"  {m['name']}: log-L1 {m['loss']:.5f}  {scalars}")
    if "bundle" in report:
        lines.append(f"bundle written to {report['bundle']}")
    return "\n".join(lines)


def _fmt(values: list[float]) -> str:
    return f"{values[0]:.4g}" if len(values) == 1 else "(" + ", ".join(f"{v:.3g}" for v in values) + ")"
