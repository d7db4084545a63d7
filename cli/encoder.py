"""``neuenh encoder train``: train a bundle's encoder (amortised starts) and write it into the bundle.

    neuenh encoder train BUNDLE [--spec SPEC.yaml] [--steps N] [--holdout 0.1] [--seed S] [-o DIR] [--json]

The bundle's modules stay frozen. The encoder (``neuenh.encoder``) learns to map a set of a
material's measurements to its parameters, on the materials of the job spec's ``data:`` sources
(by default the spec the bundle's provenance names, e.g. ``examples/reference.yaml``; paths in it
are relative to the current directory; RGL sources are refused) minus ``--holdout`` of them, held
out to measure it (``neuenh.encoder_training``). The bundle is then saved with ``encoder.safetensors``
(every file atomically, ``model.json`` last) — in place, or with ``-o DIR`` as a new bundle there; its
``model.json`` records the training and the held-out errors. A bundle that has an encoder gets a new
one. Its latent fits (``neuenh fit --capacity latent``) start from the encoder's prediction too; the
adaptive fit, ``neuenh fit``'s default, takes no start from it (``neuenh.fit.capacity.Adaptive``). A
shipped model named by its name (``enhanced-ggx``) is part of the installation: it needs ``-o`` (its
folder's path, given as BUNDLE, is rewritten in place, as for any folder).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from .outputs import output_folder
from .tables import help_description

if TYPE_CHECKING:  # torch and the encoder are imported by run_train: `neuenh encoder --help` needs neither
    from neuenh.checkpoint import Bundle

# Measurement-set sizes of the held-out comparison recorded in model.json.
HELDOUT_SIZES = (1, 30, 300, 3000)
# ``EncoderTrainConfig().steps``, written out so that the help names it without importing torch
# (tests/cli/test_encoder_cli.py keeps the two equal).
DEFAULT_STEPS = 4000


def configure(p: argparse.ArgumentParser) -> None:
    """``neuenh encoder``'s arguments, on the parser ``cli.main`` made for it (with its one-line help)."""
    p.description = help_description(__doc__)
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    train = actions.add_parser("train", help="train the encoder and write it into the bundle",
                               description=p.description)
    train.add_argument("bundle", metavar="BUNDLE", help="a bundle folder or a shipped model's name")
    train.add_argument("--spec", type=Path, help="the job spec whose data: sources to learn from "
                                                 "(default: the one the bundle's provenance names)")
    train.add_argument("--steps", type=int, default=DEFAULT_STEPS, help=f"Adam steps (default {DEFAULT_STEPS})")
    train.add_argument("--holdout", type=float, default=0.1,
                       help="share of the materials held out to measure the encoder (default 0.1)")
    train.add_argument("--pool", type=int, nargs=2, default=(4096, 2048), metavar=("UNIFORM", "MIRROR"),
                       help="measurements drawn per material, uniform and near the mirror (default 4096 2048)")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: all)")
    train.add_argument("-o", "--output", type=Path, default=None,
                       help="write the bundle with its encoder here instead of in place (needed for a shipped "
                            "model named by its name)")
    train.add_argument("--json", action="store_true", help="print the training record as JSON")
    train.set_defaults(run=run_train)


def run_train(args) -> int:
    import torch

    from neuenh.checkpoint import Bundle
    from neuenh.encoder import EncoderConfig
    from neuenh.encoder_training import EncoderTrainConfig, FixedSets, MeasurementPools, start_losses, train_encoder
    from neuenh.pretrained import bundle_path

    from .data import load_sample_spec

    if args.threads:
        torch.set_num_threads(args.threads)
    if not 0.0 <= args.holdout < 1.0:
        raise ValueError(f"--holdout is a share of the materials in [0, 1), got {args.holdout}")
    if args.steps < 1 or min(args.pool) < 1:
        raise ValueError("--steps and --pool must be at least 1")
    path = bundle_path(args.bundle)
    if path is None:
        raise ValueError(f"{args.bundle!r} is neither a bundle folder nor a shipped model")
    if args.output is not None:
        output_folder(args.output)
    elif not Path(args.bundle).is_dir():
        raise ValueError(f"{args.bundle} is a shipped model, part of the installation ({path}): give -o DIR to "
                         f"write it with its encoder as a new bundle")
    bundle = Bundle.load(path)
    spec = args.spec or _provenance_spec(bundle, path)
    sources, _, _ = load_sample_spec(spec)
    start = time.perf_counter()
    pools = MeasurementPools.from_sources(sources, *args.pool)
    order = torch.randperm(len(pools), generator=torch.Generator().manual_seed(args.seed)).tolist()
    n_held = int(round(args.holdout * len(pools)))
    if len(pools) - n_held < 1:
        raise ValueError(f"--holdout {args.holdout} leaves no material to train on ({len(pools)} in all)")
    held, train = sorted(order[:n_held]), sorted(order[n_held:])
    validation = FixedSets.of(pools.subset(held), HELDOUT_SIZES, 1024, args.seed + 1) if held else None
    config = EncoderTrainConfig(steps=args.steps, seed=args.seed, eval_every=max(1, min(250, args.steps)))
    print(f"encoder for {path}: {len(train)} materials to train on, {len(held)} held out, {args.steps} steps",
          file=sys.stderr)
    encoder, history = train_encoder(bundle.model, pools.subset(train), config, encoder_config=EncoderConfig(),
                                     fitted=bundle.materials, validation=validation,
                                     log=lambda line: print("  " + line, file=sys.stderr, flush=True))
    latent_mean = bundle.materials.mean_latent() if bundle.materials is not None else None
    heldout = {}
    if validation is not None:
        for k, size in enumerate(HELDOUT_SIZES):
            heldout[str(size)] = start_losses(bundle.model, validation.block(k, len(held)), encoder, latent_mean)
    encoder.record = {
        "spec": str(spec), "sources": [s.model_dump() for s in sources], "config": config.to_json(),
        "pool": list(args.pool), "trained_on": len(train), "heldout_materials": [pools.names[i] for i in held],
        "heldout_log_l1": heldout, "history": history, "wall_s": round(time.perf_counter() - start, 1),
        "trained_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    bundle.encoder = encoder
    path = bundle.save(args.output or path)
    if args.json:
        print(json.dumps(encoder.describe(), indent=1))
    else:
        for size, losses in heldout.items():
            print(f"held out, {size} measurements: " + ", ".join(f"{k} {v:.4f}" for k, v in losses.items()))
        print(f"wrote {path / 'encoder.safetensors'} ({encoder.describe()['n_weights']} weights)")
    return 0


def _provenance_spec(bundle: Bundle, path: Path) -> Path:
    spec = (bundle.provenance.get("search") or {}).get("spec")
    if not spec:
        raise ValueError(f"{path}: its provenance names no job spec; give one with --spec")
    return Path(spec)
