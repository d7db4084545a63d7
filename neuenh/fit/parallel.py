"""Fit many materials in several processes: ``fit_in_processes(model, samples, protocol, jobs)``.

A fit's materials are independent problems (each row's objective is its own: ``kernel``), but one
process fits them with one core: its second torch thread buys nothing at a few thousand samples a
material and costs several times beside other work, since idle OpenMP threads spin at each of the
fit's small parallel regions (docs/BENCHMARKS.md, "Fit threads"). So a studio's hundreds of
materials go to ``jobs`` processes of one thread each instead: the materials split into ``jobs``
consecutive shares of (nearly) equal counts, each share fitted by ``fit_materials`` in a process of
its own (started fresh: ``spawn``; one torch thread, freed memory kept: ``neuenh.allocator``), the
results joined in the materials' order.

Each material's record and loss are exactly what ``fit_materials`` of its share alone gives in one
thread (``shares`` says which): a fit's float rounding depends on the rows stacked beside a
material, so a fit split differently can end elsewhere within the fit's own spread, as the same
materials fitted in another order can.
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np

from ..allocator import keep_freed_memory
from ..data.samples import Samples
from ..encoder import MaterialEncoder
from ..materials import MaterialTable
from ..model import BRDFModel
from ..processes import die_with_parent
from .jit import set_fit_threads
from .protocols import FitProtocol
from .result import FitResult
from .run import fit_materials


def _start_worker() -> None:
    """A fit process: one torch and one Dr.Jit thread, freed activations kept for the next step
    (``neuenh.allocator``); it ends with the process that started it."""
    die_with_parent()
    set_fit_threads(1)
    keep_freed_memory()


def shares(materials: int, jobs: int) -> list[list[int]]:
    """The materials (indices) each of at most ``jobs`` processes fits: consecutive runs whose
    sizes differ by at most one, none empty."""
    if jobs < 1:
        raise ValueError(f"jobs must be at least 1, got {jobs}")
    return [part.tolist() for part in np.array_split(np.arange(materials), max(1, min(jobs, materials))) if len(part)]


def fit_in_processes(model: BRDFModel, samples: Samples, protocol: FitProtocol, jobs: int, *,
                     trained: MaterialTable | None = None, encoder: MaterialEncoder | None = None,
                     seed: int = 0, progress: Callable[[int, int], None] | None = None) -> FitResult:
    """``fit_materials(model, samples, protocol, trained=trained, encoder=encoder, seed=seed)`` with
    the materials split over ``jobs`` processes of one torch thread each (module doc); a single share
    (``jobs`` 1, or one material) is ``fit_materials`` here. ``wall_s`` is the whole fit's;
    ``protocol`` records the processes. ``progress(done, total)``: materials fitted so far, called
    as each share finishes."""
    start = time.perf_counter()
    total = len(samples.names)
    groups = shares(total, jobs)
    if len(groups) <= 1:  # nothing to split: this process fits it
        return fit_materials(model, samples, protocol, trained=trained, encoder=encoder, seed=seed, progress=progress)
    context = multiprocessing.get_context("spawn")  # no forked copy of this process's threads and locks
    with ProcessPoolExecutor(len(groups), mp_context=context, initializer=_start_worker) as pool:
        futures = {pool.submit(fit_materials, model, samples.select(group), protocol, trained=trained,
                               encoder=encoder, seed=seed): len(group) for group in groups}
        done = 0
        for future in as_completed(futures):
            future.result()  # a share's error stops the fit at once
            done += futures[future]
            if progress is not None:
                progress(done, total)
        results = [future.result() for future in futures]  # in the materials' order
    return FitResult.joined(results, time.perf_counter() - start, processes=len(groups))
