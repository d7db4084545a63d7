"""Fit protocols: how the per-material parameters of a frozen model are fitted to measurements.

A protocol is a small object with its own budget (Optuna-style policies): ``fit(model, samples,
start=..., trained=..., seed=...) -> FitResult``. The contract every protocol keeps:

* the model's module weights are not changed (they take no gradient during the fit and their
  ``requires_grad`` flags are restored);
* every material of ``samples`` is fitted on its own samples only, independently of the others
  fitted beside it (a material's result does not depend on which materials share the batch);
* ``start``: a ``MaterialTable`` of the same materials (names in ``samples.names`` order) to start
  from — e.g. an encoder's output; a protocol then starts there instead of its own starts;
  ``trained``: the model's training materials (a bundle's ``materials``), whose mean latent code
  is one of an enhanced model's own starts; ``encoder``: the model's encoder (a bundle's
  ``encoder``, ``neuenh.encoder``), whose prediction from a material's samples is one more of
  ``LatentAdam``'s starts (the other protocols take no start from it);
* ``FitResult.losses`` are the mean log-L1 (``train.log_l1``) of the returned parameters on each
  material's samples, and ``FitResult.protocol`` names the protocol and its budget.

The protocols:

* ``PaperRMSProp`` — the paper's Sec. 5.1: RMSProp (alpha 0.9), lr 1e-3, ``epochs`` epochs of
  minibatches of ``batch_size`` samples, from the paper's start (range means, latent 0.5).
* ``PlainLBFGS`` — for analytical models: row-wise L-BFGS on a Charbonnier surrogate
  (``optim.lbfgs_rows``), at most ``iterations`` per surrogate phase, from the paper's start and
  from where ``warmup_epochs`` Adam epochs took it (one start per ``warmup_lrs``), side by side; each
  material keeps the lowest.
  The warm-ups and the warm-up starts' first phase see a random subset of ``coarse_slots`` samples.
* ``LatentAdam`` — an enhanced model's latent code and analytical parameters by row-wise Adam
  (``epochs``, lr ``lr`` with cosine decay), from several starts stacked as rows of one batch and
  narrowed to each material's best after half the epochs (class doc).
* ``Adaptive`` (``neuenh.fit.capacity``) — beyond the latent code, per-material corrections of
  module weights under a prior, capacity and prior strength chosen per material by
  cross-validation on the fit data.

``default_protocol(model)``: ``PlainLBFGS`` for a model without modules, ``LatentAdam`` for one with
(``Adaptive`` when asked for: ``FitOptions(capacity="auto")``, ``neuenh fit --capacity auto``).
"""

from __future__ import annotations

import dataclasses
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import torch

from ..data.samples import Samples
from ..encoder import MaterialEncoder
from ..materials import LATENT_INIT, MaterialTable
from ..model import BRDFModel
from ..optimizers import RMSProp
from ..train import log_l1, predict
from .jit import KERNELS, row_kernel
from .kernel import RowKernel, RowLosses, RowSpace, frozen
from .layout import compacted, layout_rows, padded
from .optim import SURROGATE_EPS, Adam, adam_rows, evaluate_rows, lbfgs_rows
from .result import FitResult, per_material_loss

# Codes × samples the training codes' screen scores at once (``LatentAdam.screened_codes``): a 32-wide activation of
# 32 MiB, glibc's largest mmap threshold (docs/BENCHMARKS.md, "Blocks and chunks of a fit: measured by hand"); the
# shipped model's 260 codes × 1,000 samples are one group.
SCREEN_SLOTS = 262_144


class FitProtocol(ABC):
    """How materials are fitted with a frozen model: the contract is the module doc's."""

    name: ClassVar[str]
    # The most samples ``fit_materials`` fits at once with this protocol (``run.blocks``): enough rows to share a
    # step's fixed cost, few enough to bound its memory (12 kB a sample for the adaptive fit; docs/BENCHMARKS.md,
    # "A fit's memory, bounded by blocks of materials").
    block_samples: ClassVar[int] = 100_000

    @abstractmethod
    def fit(self, model: BRDFModel, samples: Samples, *, start: MaterialTable | None = None,
            trained: MaterialTable | None = None, encoder: MaterialEncoder | None = None, seed: int = 0) -> FitResult:
        """Fit every material of ``samples`` (module doc)."""

    def describe(self) -> dict:
        """The protocol's name and budget, as plain data (fit reports, provenance)."""
        return {"name": self.name, **dataclasses.asdict(self)}

    @property
    @abstractmethod
    def budget_epochs(self) -> int:
        """The fit's budget as epochs over a material's samples, counted as the protocol counts
        them (RMSProp or Adam epochs, L-BFGS iterations per phase; an adaptive fit, its latent epochs)."""

    def work(self, samples: Samples) -> int:
        """The fit's work in measurement-epochs: each measurement it reads times the epochs it reads
        it, what a service's limit on one fit bounds (``NEUENH_MAX_FIT_WORK``). Here every sample
        for ``budget_epochs``; protocols that read fewer, or read some twice, say so."""
        return len(samples) * self.budget_epochs


def _check(model: BRDFModel, samples: Samples, start: MaterialTable | None) -> None:
    if len(samples) == 0:
        raise ValueError("no samples to fit")
    if start is not None and (tuple(start.names) != tuple(samples.names) or start.specs.names != model.specs.names
                              or start.latent_dim != model.latent_dim):
        raise ValueError(f"the start's materials {list(start.names)} and parameters must be the fit's "
                         f"({list(samples.names)}, {list(model.specs.names)}, latent {model.latent_dim})")


def paper_start(model: BRDFModel, names) -> MaterialTable:
    """The paper's start: every analytical parameter at the mean of its range, latent 0.5."""
    return MaterialTable(model.specs, names, model.latent_dim)


class Rows:
    """A fit's samples, padded per material (``layout.padded``), and the layouts of its rows."""

    def __init__(self, samples: Samples, seed: int = 0):
        self.names = samples.names
        self.wi, self.wo, self.f_r, self.valid = padded(samples, seed)

    @property
    def materials(self) -> int:
        return len(self.names)

    def as_problems(self, material: torch.Tensor, train: torch.Tensor) -> "Rows":
        """Rows whose i-th "material" is material ``material[i]`` seen through the slots ``train[i]``
        only (e.g. every cross-validation fold of every material as a problem of its own), those
        slots moved to the front of a narrower grid (``layout.compacted``)."""
        out = Rows.__new__(Rows)
        out.names = tuple(self.names[i] for i in material.tolist())
        out.wi, out.wo, out.f_r, out.valid = compacted(self.wi[material], self.wo[material], self.f_r[material],
                                                       train & self.valid[material])
        return out

    def layout(self, material: torch.Tensor, train: torch.Tensor | None = None, val: torch.Tensor | None = None):
        """Rows fitting ``material`` (rows,), on all of each material's samples unless ``train``
        (rows, slots) says otherwise, validated on ``val`` (default none)."""
        train = self.valid[material] if train is None else train
        val = torch.zeros_like(train) if val is None else val
        return layout_rows(self.wi, self.wo, self.f_r, material, train, val)


def _table(model: BRDFModel, space: RowSpace, x: torch.Tensor, names, latent: torch.Tensor | None = None) -> MaterialTable:
    table = MaterialTable(model.specs, names, model.latent_dim, latent=latent)
    return space.to_table(x, table)


@dataclass(frozen=True)
class PaperRMSProp(FitProtocol):
    """The paper's protocol (Sec. 5.1): RMSProp (alpha 0.9), ``lr``, ``epochs`` epochs of shuffled
    minibatches of ``batch_size`` samples, from the paper's start (or ``start``)."""

    name: ClassVar[str] = "paper"
    epochs: int = 1000
    lr: float = 1e-3
    batch_size: int = 100_000

    def __post_init__(self) -> None:
        if self.epochs < 1 or self.lr <= 0 or self.batch_size < 1:
            raise ValueError(f"invalid paper protocol {self}")

    @property
    def budget_epochs(self) -> int:
        return self.epochs

    def fit(self, model, samples, *, start=None, trained=None, encoder=None, seed=0, trace_every: int = 0) -> FitResult:
        _check(model, samples, start)
        start_time = time.perf_counter()
        materials = paper_start(model, samples.names) if start is None else _copy(start)
        optimizer = RMSProp(materials.parameters(), lr=self.lr, alpha=0.9)
        generator = torch.Generator().manual_seed(seed)
        trace: list[tuple[float, float]] = []
        full_batch = len(samples) <= self.batch_size
        with frozen(model):
            for epoch in range(self.epochs):
                order = slice(None) if full_batch else torch.randperm(len(samples), generator=generator)
                for lo in range(0, len(samples), self.batch_size):
                    index = order if full_batch else order[lo : lo + self.batch_size]
                    loss = log_l1(predict(model, materials, samples, index), samples.f_r[index], samples.wi[index]).mean()
                    optimizer.zero_grad()
                    loss.backward()
                    optimizer.step()
                if trace_every and (epoch % trace_every == 0 or epoch == self.epochs - 1):
                    trace.append((time.perf_counter() - start_time, float(sum(per_material_loss(model, materials, samples)))
                                  / len(samples.names)))
            losses = per_material_loss(model, materials, samples)
        materials.requires_grad_(False)
        return FitResult(materials, losses, time.perf_counter() - start_time, self.describe(), trace=trace)


def _copy(table: MaterialTable) -> MaterialTable:
    return MaterialTable(table.specs, table.names, table.latent_dim,
                         {k: v.detach().clone() for k, v in table.raw.items()}, table.latent.detach().clone())


@dataclass(frozen=True)
class PlainLBFGS(FitProtocol):
    """Row-wise L-BFGS (at most ``iterations`` per surrogate phase) from the paper's start (or
    ``start``) and, as rows of the same batch, from where ``warmup_epochs`` Adam epochs took it: one
    warm-up start for each lr of ``warmup_lrs`` (with a second one, the jit kernel's fits were lower on
    the whole at about half today's CPU, but failed their rules; with a third and ``warmup_subsets``, they
    passed two fresh draws and missed the visible 8 on one material: docs/BENCHMARKS.md, "Stop 73", "Stop 74",
    "Stop 76", "Stop 77"); a warm-up at another's lr on the same slots is dropped. ``jitter_starts`` more starts
    run beside the given one on every sample, each the given one moved by ``jitter`` * N(0, 1), one offset for every row (the jit
    kernel with one passed a fresh draw and missed the visible 8 on one material: "Stop 78"). Each material
    keeps the end point of lowest loss. All always run: a first end point can be a wrong minimum that
    nothing in its own numbers flags (docs/BENCHMARKS.md, "Issue 24's latent and plain
    fits"). Meant for analytical models (an enhanced model's landscape is rough for L-BFGS).

    The given starts (``first``, its jittered copies and ``also`` in ``fit_rows``) run every phase on every sample. The
    warm-up starts only diversify the basins tried, so they and their first surrogate phase
    (``SURROGATE_EPS[0]``, which settles the basin) see at most ``coarse_slots`` of each row's
    samples — its first slots, a random subset since rows keep their samples shuffled with the valid
    ones first (``layout.padded``, ``layout.compacted``), or with ``warmup_subsets`` warm-up ``k``'s from
    slot ``k * coarse_slots`` on, kept inside every row's samples; its last phase sees all of them. A
    material's result is never worse than what the given starts alone reach (docs/BENCHMARKS.md, "Plain fits
    against NBRDF and before")."""

    name: ClassVar[str] = "plain"
    iterations: int = 300
    warmup_epochs: int = 100
    warmup_lrs: tuple[float, ...] = (0.05,)
    coarse_slots: int = 2000
    warmup_subsets: bool = False  # each warm-up start (and its first phase) on its own coarse subset
    jitter_starts: int = 0  # more starts on all samples: ``first`` plus ``jitter`` * N(0, 1) on its raw values
    jitter: float = 0.01
    kernel: str = "torch"  # neuenh.fit.jit.KERNELS

    def __post_init__(self) -> None:
        if (self.iterations < 1 or self.warmup_epochs < 0 or not self.warmup_lrs
                or any(lr <= 0 for lr in self.warmup_lrs) or self.coarse_slots < 1 or self.jitter_starts < 0
                or not self.jitter > 0 or self.kernel not in KERNELS):
            raise ValueError(f"invalid plain protocol {self}")

    @property
    def budget_epochs(self) -> int:
        return self.iterations

    def fit(self, model, samples, *, start=None, trained=None, encoder=None, seed=0) -> FitResult:
        _check(model, samples, start)
        start_time = time.perf_counter()
        rows = Rows(samples, seed)
        space = RowSpace(model)
        first = space.from_table(paper_start(model, samples.names) if start is None else start)
        with frozen(model):
            x, scored = self.fit_rows(row_kernel(model, space, self.kernel), first,
                                      rows.layout(torch.arange(rows.materials)))
        table = _table(model, space, x, samples.names)
        return FitResult(table, scored.train.tolist(), time.perf_counter() - start_time, self.describe())

    def fit_rows(self, kernel: RowKernel, first: torch.Tensor, layout, also: torch.Tensor | None = None
                 ) -> tuple[torch.Tensor, "RowLosses"]:
        """Every row of ``layout`` from ``first`` (rows, dim), from its Adam warm-ups and from
        ``also`` (rows, dim) when given (e.g. a fit of part of the same samples), each row keeping
        the end point of lowest fit loss: (rows, dim) and their losses."""
        r = layout.rows
        coarse = layout.chunk(0, min(layout.slots, self.coarse_slots))
        width, subsets = coarse.slots, self.warmup_subsets and coarse is not layout
        fewest = int((layout.train > 0).sum(1).min())  # warm-up k from slot k * width, inside every row's samples
        lows = [max(0, min(k * width, fewest - width)) if subsets else 0 for k in range(len(self.warmup_lrs))]
        # a warm-up at another's lr on the same slots would end where it does
        lrs, lows = zip(*dict.fromkeys(zip(self.warmup_lrs, lows)))
        warmups = len(lrs)
        if warmups == 1:  # no copies of the rows (the adaptive fit runs this on all its folds' rows)
            coarse_warmups, starts, lr_scale = coarse, first, None
        else:  # the warm-ups as rows of one batch, lr and slots block by block
            coarse_warmups, starts = layout.windows(lows, width), first.repeat(warmups, 1)
            lr_scale = (torch.tensor(lrs) / lrs[0]).repeat_interleave(r)
        warmed = adam_rows(kernel, starts, coarse_warmups, Adam(self.warmup_epochs, lrs[0]), lr_scale=lr_scale).x
        # one offset per jittered start, the same at every call and for every row: a material's starts do not
        # depend on the materials fitted beside it
        noise = torch.Generator().manual_seed(0)
        jittered = [first + self.jitter * torch.randn(1, first.shape[1], generator=noise)
                    for _ in range(self.jitter_starts)]
        given = [first, *jittered] + ([] if also is None else [also])
        k = len(given) + warmups
        every = layout.select(torch.arange(r).repeat(k))  # rows: first, warmed (one per lr), jittered, also
        if coarse is layout:  # no subset: every start's first phase in one batch
            x, _ = lbfgs_rows(kernel, torch.cat([first, warmed, *given[1:]]), every, self.iterations,
                              SURROGATE_EPS[:1])
        else:
            settled = lbfgs_rows(kernel, torch.cat(given), layout.select(torch.arange(r).repeat(len(given))),
                                 self.iterations, SURROGATE_EPS[:1])[0]
            warm = lbfgs_rows(kernel, warmed, coarse_warmups, self.iterations, SURROGATE_EPS[:1])[0]
            x = torch.cat([settled[:r], warm, settled[r:]])
        x, _ = lbfgs_rows(kernel, x, every, self.iterations, SURROGATE_EPS[1:])
        x = x.float()
        scored = evaluate_rows(kernel, x, every)
        best = scored.train.reshape(k, r).argmin(0)
        pick = lambda t: t.reshape(k, r, *t.shape[1:])[best, torch.arange(r)]
        return pick(x), RowLosses(pick(scored.train), pick(scored.val), pick(scored.objective), None)


@dataclass(frozen=True)
class LatentAdam(FitProtocol):
    """An enhanced model's latent code and analytical parameters by row-wise Adam: ``epochs``
    full-batch epochs, lr ``lr`` decaying by a cosine to 1e-3 of it.

    Starts (``starts="analytical"``, beyond the paper; or ``start`` alone when given): the modules
    were trained on materials whose analytical parameters had been fitted first, so the paper's
    start can leave a new material in a poor basin. The analytical model of the same graph is fitted
    first (Adam, the same budget); the enhanced model is made to imitate that fit (all its
    parameters fitted to the analytical fit's predictions at the same directions, a third of the
    epochs), from latent 0.5 and from the training materials' mean code when ``trained`` is given.
    With ``trained``, also a start from the training codes: every training material's latent code
    beside the material's analytical fit is scored on at most ``screen_samples`` of its samples (no
    step taken); the ``screened`` of lowest loss race for a quarter of the epochs on those samples
    only, and the winner's end point is one more start. Each imitation, that start and the paper's
    then start the fit to the measurements, stacked as rows of one batch; after ``narrow_at`` (half)
    of the epochs each material keeps its lowest-loss start — from half on, the start that running
    every start to its end keeps (docs/BENCHMARKS.md, "The latent fit's starts narrowed at half").
    ``kernel``: every stage's rows' kernel (``neuenh.fit.jit.row_kernel``), by default "auto": jit for
    a fit of at least ``JIT_MIN_WORK`` measurement-epochs, torch for smaller ones and where Dr.Jit is
    not available. With the model's ``encoder`` (a bundle's:
    ``neuenh.encoder``), its prediction from the material's samples is one start more, last. Measured
    on 26 held-out training-source materials it lowered 8 of them (by up to 35 %) on either protocol,
    but on the uniform one raised two by 13 % and 34 %, so the shipped model carries none
    (docs/BENCHMARKS.md, "The encoder as a start").
    ``starts="paper"``: the paper's start alone.

    Why screened codes: the fit's end point depends on its start more than on anything else — one
    material's held-out error moved 1.6× when only the order of its samples changed — and a few
    hundred training codes are a cheap, diverse set of starts the modules were trained to read
    (docs/BENCHMARKS.md, "Latent fits: the training codes' start").

    A material with more than ``sample_cap`` samples is fitted to a seeded random ``sample_cap`` of
    them (None: all): its few dozen parameters end where 100,000 samples put them from about 20,000
    on, while the fit's time grows with every sample (docs/BENCHMARKS.md, "Latent fits of many
    samples").

    ``coarse_slots`` (None: off): the starts are raced on at most that many of each material's
    samples — up to the narrowing, the stacked starts see each row's first ``coarse_slots`` slots, a
    random subset (``layout.padded``) — and only the start each material keeps, chosen by its loss
    on all of them, runs on all of them: the race only chooses a basin, while every start costs its
    samples. The starts themselves (the analytical fit and the imitations) are made on every sample:
    made on the subset too, they cost two of rule q's 20 materials ~1.5x their held-out error
    (docs/BENCHMARKS.md, "Stop 71")."""

    name: ClassVar[str] = "latent"
    # Its fastest block (0.8x the time of blocks of 72,000-100,000): its four starts a material take 512 bytes a
    # sample in its widest activation, which above ~65,000 samples passes glibc's largest mmap threshold (32 MiB) and
    # gets fresh pages every step (docs/BENCHMARKS.md, "Blocks and chunks of a fit: measured by hand").
    block_samples: ClassVar[int] = 40_000
    epochs: int = 300
    lr: float = 0.05
    starts: str = "analytical"
    screened: int = 8
    screen_samples: int = 1000
    sample_cap: int | None = 20_000
    # Rule m (docs/BENCHMARKS.md, "Stop 68"): on 20 new training-source materials, the jit kernel with the starts
    # narrowed at half the epochs took 0.46x / 0.49x the CPU time of torch's kernel narrowing after a quarter
    # (mirror 3,000 / uniform 10,000), at held-out geometric means 0.944 / 0.966; from half on the narrowing keeps
    # the start that running every start to its end keeps, so an end point depends less on the kernels' rounding,
    # which alone failed rule l. "auto": jit from ``JIT_MIN_WORK`` on (a model's first jit fit on a machine
    # compiles), torch below it and where Dr.Jit is not available.
    kernel: str = "auto"  # neuenh.fit.jit.KERNELS: every stage's rows (auto: by the fit's work, ``JIT_MIN_WORK``)
    narrow_at: float = 0.5  # the share of the epochs after which each material keeps its best start
    coarse_slots: int | None = None  # the race's samples per material until the narrowing (class doc)

    def __post_init__(self) -> None:
        if (self.epochs < 1 or self.lr <= 0 or self.starts not in ("analytical", "paper") or self.screened < 0
                or self.screen_samples < 1 or (self.sample_cap is not None and self.sample_cap < 1)
                or self.kernel not in KERNELS or not 0 <= self.narrow_at < 1
                or (self.coarse_slots is not None and self.coarse_slots < 1)):
            raise ValueError(f"invalid latent protocol {self} (starts: 'analytical' or 'paper')")

    @property
    def budget_epochs(self) -> int:
        return self.epochs

    def work(self, samples: Samples) -> int:
        """At most ``sample_cap`` of each material's samples for every epoch; with ``coarse_slots``, at
        most that many of them until the narrowing."""
        every = samples.count_at_most(self.sample_cap)
        if self.coarse_slots is None:
            return every * self.epochs
        coarse = samples.count_at_most(min(self.coarse_slots, self.sample_cap or self.coarse_slots))
        narrowed = int(self.narrow_at * self.epochs)
        return coarse * narrowed + every * (self.epochs - narrowed)

    def fit(self, model, samples, *, start=None, trained=None, encoder=None, seed=0) -> FitResult:
        _check(model, samples, start)
        start_time = time.perf_counter()
        if self.sample_cap is not None:
            samples = samples.at_most(self.sample_cap, seed)
        rows = Rows(samples, seed)
        with frozen(model):
            encoded = encoder.encode(samples) if encoder is not None and start is None and self.starts == "analytical" \
                else None
            x, losses = self.fit_rows(model, rows, start, trained, seed, encoded=encoded)
        space = RowSpace(model)
        table = _table(model, space, x, samples.names)
        return FitResult(table, losses.tolist(), time.perf_counter() - start_time,
                         {**self.describe(), "encoder_start": encoded is not None})

    def _kernel(self, model: BRDFModel, space: RowSpace, rows: Rows) -> RowKernel:
        """Every stage's kernel, chosen by the whole fit's work (its materials' samples times ``epochs``)."""
        return row_kernel(model, space, self.kernel, work=int(rows.valid.sum()) * self.epochs)

    def starts_of(self, model: BRDFModel, rows: Rows, trained: MaterialTable | None, seed: int,
                  train: torch.Tensor | None = None) -> list[torch.Tensor]:
        """The starting rows (m, dim) of every material (class doc); ``train`` (m, slots): the
        samples each material's analytical fit and imitations may see (default all)."""
        m = rows.materials
        space = RowSpace(model)
        paper = space.from_table(paper_start(model, rows.names))
        if self.starts == "paper" or not model.has_modules:
            return [paper]
        analytical = model.enhance(model.analytical_state(), seed)
        a_space = RowSpace(analytical)
        a_kernel = self._kernel(analytical, a_space, rows)
        layout = rows.layout(torch.arange(m), train)
        base = adam_rows(a_kernel, a_space.from_table(paper_start(analytical, rows.names)), layout,
                         Adam(self.epochs, self.lr)).x
        with torch.no_grad():
            values, _ = a_space.values(base)
            imitated_f = analytical.forward_indexed(layout.wi, layout.wo, values, None, layout.grid).clamp_min(0.0)
        latents = [torch.full((m, model.latent_dim), LATENT_INIT)]
        mean = trained.mean_latent() if trained is not None and model.uses_latent else None
        if mean is not None:
            latents.append(mean.reshape(1, -1).expand(m, -1))
        k = len(latents)
        like = torch.cat([torch.cat([base, latent], 1) if space.latent else base for latent in latents])
        imitate = rows.layout(torch.arange(m).repeat(k), None if train is None else train.repeat(k, 1)).with_targets(
            imitated_f.reshape(m, -1, 3).repeat(k, 1, 1))
        imitated = adam_rows(self._kernel(model, space, rows), like, imitate, Adam(max(1, self.epochs // 3), self.lr)).x
        return [paper, *imitated.reshape(k, m, -1), *self.screened_starts(model, rows, trained, base, train)]

    def screened_starts(self, model: BRDFModel, rows: Rows, trained: MaterialTable | None, base: torch.Tensor,
                        train: torch.Tensor | None = None) -> list[torch.Tensor]:
        """The training codes' start (class doc), [(m, dim)], or [] without training codes: the
        ``screened_codes`` raced by Adam on the samples they were scored on; each material's end
        point of lowest loss."""
        space = RowSpace(model)
        if not self.screened or trained is None or not trained.coded() or not space.latent:
            return []
        usable = rows.valid if train is None else rows.valid & train
        subset = rows.as_problems(torch.arange(rows.materials), usable & (usable.cumsum(1) <= self.screen_samples))
        kernel = self._kernel(model, space, rows)  # the whole fit's, not the subset's
        screened = self.screened_codes(model, subset, trained, base, kernel=kernel)  # (m, k, dim)
        m, k, dim = screened.shape
        race = adam_rows(kernel, screened.reshape(m * k, dim),
                         subset.layout(torch.arange(m).repeat_interleave(k)), Adam(max(1, self.epochs // 4), self.lr))
        winner = race.train.reshape(m, k).nan_to_num(torch.inf).argmin(1)
        return [race.x.reshape(m, k, dim)[torch.arange(m), winner]]

    def screened_codes(self, model: BRDFModel, rows: Rows, trained: MaterialTable, base: torch.Tensor,
                       slots_at_once: int = SCREEN_SLOTS, kernel: RowKernel | None = None) -> torch.Tensor:
        """(m, k, dim): for each material of ``rows``, its analytical fit ``base`` (m, analytical
        dim) beside each of the ``screened`` training codes of lowest loss on all its samples as they
        are (no step taken), lowest first (k = at most ``screened``). The codes are scored in groups of
        at most ``slots_at_once`` codes × samples, so a bundle of many training materials screens in
        bounded memory; ``kernel``: the fit's (default: chosen by ``rows``' work)."""
        kernel = kernel or self._kernel(model, RowSpace(model), rows)
        codes = trained.latent_codes().float()
        group = max(1, slots_at_once // rows.wi.shape[1])
        best = []
        for i in range(rows.materials):  # one material at a time: a row per code, on its slots
            candidates = torch.cat([base[i].expand(len(codes), -1), codes], 1)
            loss = torch.cat([evaluate_rows(kernel, part, rows.layout(torch.full((len(part),), i))).train
                              for part in torch.split(candidates, group)])
            best.append(candidates[loss.argsort()[: self.screened]])
        return torch.stack(best)

    def fit_rows(self, model: BRDFModel, rows: Rows, start: MaterialTable | None, trained: MaterialTable | None,
                 seed: int, train: torch.Tensor | None = None, val: torch.Tensor | None = None,
                 encoded: MaterialTable | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(m, dim) fitted rows and their (m,) fit losses; ``train``/``val`` (m, slots) restrict each
        material's fit to some of its samples (cross-validation folds); ``encoded``: the encoder's
        prediction, one more start beside the protocol's own (class doc)."""
        m = rows.materials
        space = RowSpace(model)
        starts = [space.from_table(start)] if start is not None else self.starts_of(model, rows, trained, seed, train)
        if encoded is not None:
            starts.append(space.from_table(encoded))
        k = len(starts)
        material = torch.arange(m).repeat(k)
        layout = rows.layout(material, None if train is None else train.repeat(k, 1),
                             None if val is None else val.repeat(k, 1))
        kernel = self._kernel(model, space, rows)
        coarse = layout if self.coarse_slots is None or k == 1 else layout.chunk(0, min(layout.slots, self.coarse_slots))
        result = adam_rows(kernel, torch.cat(starts), coarse, Adam(self.epochs, self.lr),
                           groups=material if k > 1 else None, narrow_at=self.narrow_at,
                           narrowed_layout=None if coarse is layout else layout)
        return result.x, result.train

