"""``fit_materials``: the one entry of a fit — a protocol run over blocks of the materials.

A fit stacks its materials as rows of one batch (``layout``), so its memory grows with the samples
fitted at once: 12 kB a sample for the adaptive fit and 9 kB for the latent one (the shipped
``enhanced-ggx``), so a studio's two hundred materials of 10,000 samples would not fit in 24 GiB. The
materials are fitted in consecutive blocks whose batch holds at most the protocol's ``block_samples``
samples (100,000; the latent fit's 40,000, where it runs fastest), each material padded to the block's
largest (a material with more is a block of its own), and joined in order: 64 materials of 10,000
samples then take 0.2x the memory of one batch, and less time, not more (docs/BENCHMARKS.md, "A fit's
memory, bounded by blocks of materials"). A block still holds enough rows for the steps' fixed cost to
be shared (eight materials in one batch take two thirds of their time one at a time), and fits of fewer
samples are one block: the fit itself. A material's result is its block's fit, which — as for
``--jobs``' shares (``parallel``) — may differ from a fit beside other materials by float rounding only.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from ..data.samples import Samples
from ..encoder import MaterialEncoder
from ..materials import MaterialTable
from ..model import BRDFModel
from .options import FitOptions
from .protocols import FitProtocol
from .result import FitResult


def default_protocol(model: BRDFModel) -> FitProtocol:
    """``PlainLBFGS`` for a model without modules, ``LatentAdam`` (the latent capacity) for one with:
    ``FitOptions()``'s protocol."""
    return FitOptions().protocol_for(model)


def blocks(counts: list[int], block_samples: int) -> list[list[int]]:
    """Consecutive runs of material indices whose batch — every material padded to the run's largest
    sample count (``layout.padded``) — holds at most ``block_samples`` slots (a material with more
    alone), none empty: a few large materials after many small ones do not pad them all to their size."""
    if block_samples < 1:
        raise ValueError(f"block_samples must be at least 1, got {block_samples}")
    out: list[list[int]] = []
    widest = 0
    for i, count in enumerate(counts):
        if not out or (len(out[-1]) + 1) * max(widest, count) > block_samples:
            out.append([])
            widest = 0
        out[-1].append(i)
        widest = max(widest, count)
    return out


def fit_materials(model: BRDFModel, samples: Samples, protocol: FitProtocol | None = None, *,
                  start: MaterialTable | None = None, trained: MaterialTable | None = None,
                  encoder: MaterialEncoder | None = None, seed: int = 0, block_samples: int | None = None,
                  progress: Callable[[int, int], None] | None = None) -> FitResult:
    """Fit every material of ``samples`` with ``model`` frozen by ``protocol`` (default:
    ``default_protocol(model)``), in blocks of at most ``block_samples`` padded samples (``blocks``;
    default the protocol's own, ``FitProtocol.block_samples``);
    ``start``, ``trained`` and ``encoder`` as ``FitProtocol.fit`` takes them. ``progress(done, total)``:
    materials fitted so far, after each block."""
    protocol = protocol or default_protocol(model)
    began, total = time.perf_counter(), len(samples.names)
    parts = []
    block_samples = protocol.block_samples if block_samples is None else block_samples
    for block in blocks(samples.counts().tolist(), block_samples):
        whole = len(block) == total
        parts.append(protocol.fit(model, samples if whole else samples.select(block),
                                  start=start if whole or start is None else start.subset(block),
                                  trained=trained, encoder=encoder, seed=seed))
        if progress is not None:
            progress(block[-1] + 1, total)
    if len(parts) == 1:
        return parts[0]
    return FitResult.joined(parts, time.perf_counter() - began, blocks=len(parts))
