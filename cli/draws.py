"""How both command lines (``neuenh fit``, ``neuenh-client fit``) turn a measured file into
measurements: an RGL ``.bsdf`` or a MERL ``.binary`` is a continuous material, so pairs are drawn from
it — ``--samples`` of them (default 3,000), ``--near-mirror`` of those with the half vector near the
normal (default 0.5, where a glossy material's highlight is), seeded by ``--seed`` — by
``neuenh.study.heldout.draw_fit_test``, which also draws the held-out pairs. Tables have their rows.

Nothing here imports torch until a file is found to be measured (a table's path stays numpy-only).
"""

from __future__ import annotations

import argparse
import os

from neuenh.data.draws import DRAW_NEAR_MIRROR, DRAW_SAMPLES

READABLE = "measurement tables (.npz, CSV), RGL .bsdf and MERL .binary files"


def add_draw_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--samples", type=int, default=DRAW_SAMPLES, metavar="N",
                   help=f"pairs drawn from each measured file (default {DRAW_SAMPLES:,}; tables have their rows)")
    p.add_argument("--near-mirror", type=float, default=DRAW_NEAR_MIRROR, metavar="F",
                   help=f"the share of those pairs with the half vector near the normal (default {DRAW_NEAR_MIRROR})")
    p.add_argument("--seed", type=int, default=0, help="the draws' seed (default 0)")


def check_draw_arguments(args: argparse.Namespace, test_samples: int | None = None) -> None:
    """Usage errors of the draw's arguments (``ValueError``)."""
    for flag, value in (("--samples", args.samples), ("--test-samples", test_samples)):
        if value is not None and value < 1:
            raise ValueError(f"{flag} must be at least 1, got {value}")
    if not 0.0 <= args.near_mirror <= 1.0:
        raise ValueError(f"--near-mirror is a share of the pairs, in [0, 1]; got {args.near_mirror}")


def is_measured(path: str | os.PathLike) -> bool:
    """True for an RGL or MERL file, False for a table; a ``ValueError`` naming anything else."""
    from neuenh.data.errors import DataError
    from neuenh.data.formats import fit_kind

    try:
        return fit_kind(path) != "table"
    except DataError as exc:
        raise ValueError(f"{exc}; a fit reads {READABLE}") from None


def draw(path: str | os.PathLike, args: argparse.Namespace, test_samples: int | None = None):
    """(fit, held-out or None) ``Samples`` drawn from the measured file at ``path`` with ``args``'
    draw (``neuenh.study.heldout.draw_measured``)."""
    from neuenh.study.heldout import draw_measured

    return draw_measured(path, args.samples, args.near_mirror, args.seed, test_samples)
