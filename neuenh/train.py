"""Train one candidate enhancement state: what a search worker runs.

``train_candidate(parent, state, data, config, seed)`` builds the candidate from its parent
(``BRDFModel.enhance``: shared modules keep their trained weights, new ones start fresh from
``seed``, reverted ones are dropped; every material keeps the parent's parameters), then trains
module weights, latent and analytical parameters of every material jointly for ``config.epochs``
epochs (paper Sec. 4.2-4.3):

    L = mean_k | log(1 + f_gt(wi, wo) cos_i) - log(1 + f_pred(wi, wo) cos_i) |

with ``cos_i`` taken about the ground-truth (geometric) normal, RMSProp (alpha 0.9, lr 1e-3) and a
batch size of 100K. It is a pure function of its inputs: the same inputs give bit-identical losses
on the same CPU with the same thread count.
"""

from __future__ import annotations

import contextlib
import copy
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable, Iterator, Literal

import torch

from .checkpoint import Bundle
from .data.samples import Samples, TrainingData
from .model import BRDFModel
from .optimizers import CosineSchedule, RMSProp
from .materials import LATENT_INIT, MaterialTable


SCORE_CAPACITIES = ("latent", "auto")  # FitScoreConfig.capacity: a fixed capacity, or the users' own choice


@dataclass(frozen=True)
class FitScoreConfig:
    """How ``neuenh.selection`` scores a trained candidate on materials kept out of training: each
    held-out material's parameters are fitted (modules frozen, ``fit.fit_materials``, ``epochs``) to
    ``fit_samples`` of its samples, and the log-L1 is measured on up to ``test_samples`` others.
    ``epochs`` is the users' fit's (``fit.protocols.LatentAdam.epochs``): fits of 100 epochs end
    higher (30-70 % on synthetic materials, 2.4x on held-out stand-ins) and ranked a search's rounds
    otherwise than users' fits do (docs/BENCHMARKS.md, "Stop 60"). ``capacity``: what each material's
    fit may free (``fit.FitOptions.capacity``): ``latent`` (its code and analytical parameters) or
    ``auto``, the users' default (``neuenh.capacities.USER_CAPACITY``), at about twice the price."""

    fit_samples: int = 1000
    test_samples: int = 4000
    epochs: int = 300
    seed: int = 0
    capacity: str = "latent"

    def __post_init__(self) -> None:
        if self.fit_samples < 1 or self.test_samples < 1 or self.epochs < 1 or self.capacity not in SCORE_CAPACITIES:
            raise ValueError(f"invalid fit score config {self}")


# TrainConfig.precision (and the job spec's train.precision) -> the dtype of the step's matrix
# products under autocast (None: no autocast).
Precision = Literal["float32", "bfloat16"]
PRECISIONS: dict[Precision, torch.dtype | None] = {"float32": None, "bfloat16": torch.bfloat16}


def native_bfloat16() -> bool:
    """Whether this CPU multiplies bfloat16 in hardware (AVX512_BF16 or AMX tiles). Elsewhere (AVX2
    alone) bfloat16 products are emulated: the compiled step about 7x slower than in float32
    (docs/BENCHMARKS.md, "The compiled training step")."""
    return torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported()


@dataclass(frozen=True)
class TrainConfig:
    epochs: int = 30
    lr: float = 1e-3
    rmsprop_alpha: float = 0.9
    batch_size: int = 100_000
    eval_batch_size: int = 200_000
    # None: a constant lr (the paper). Otherwise the lr follows a cosine from ``lr`` down to
    # ``lr_final`` over the candidate's epochs, so candidates are compared settled, not mid-step.
    lr_final: float | None = None
    # Compile the training step with torch.compile (needs a C++ compiler): measured in
    # bench/bench_speed.py at 2.1-2.5x (batch 4096) and 2.1x (batch 1e5, in slices) the eager step, after 5-20 s
    # of compiling per batch shape, so it pays from a few hundred steps on.
    compile: bool = False
    # "bfloat16": the step's matrix products in bfloat16 (torch.autocast: the modules' activations
    # between layers too; analytical terms, loss, parameters and optimiser stay float32). On CPUs with
    # bfloat16 arithmetic (AVX512_BF16, AMX) the compiled step at batch 1e5 ran 1.7x the float32 one (unsliced),
    # at 4,096 about as fast, and near convergence it trains 3-10 % worse (docs/BENCHMARKS.md, "The compiled
    # training step"). Validation, fit scores and fits always run in float32. Without it (AVX2 alone)
    # the products are emulated and the step is about 7x slower: ``train_candidate`` warns.
    precision: Precision = "float32"
    # After training, score the candidate by fitting the data's held-out materials (``neuenh.selection``
    # does, in the worker); None: no fit score.
    fit_score: FitScoreConfig | None = None
    # Weight of a Gaussian prior on every material's latent code about LATENT_INIT, the start of every
    # training code and of every fit (an auto-decoder's code prior: Park et al. 2019, "DeepSDF", Sec. 4):
    # each batch's loss gains latent_prior times the mean over its samples of their material's
    # mean_d (z_d - LATENT_INIT)^2 (``batch_loss``). 0: no prior (the paper).
    latent_prior: float = 0.0

    def __post_init__(self) -> None:
        if self.epochs < 0 or self.batch_size < 1 or self.lr <= 0 or not 0 <= self.rmsprop_alpha < 1 \
                or (self.lr_final is not None and not 0 < self.lr_final <= self.lr) \
                or self.precision not in PRECISIONS or not 0 <= self.latent_prior < math.inf:
            raise ValueError(f"invalid training config {self}")

    def to_json(self) -> dict:
        out = {"epochs": self.epochs, "lr": self.lr, "rmsprop_alpha": self.rmsprop_alpha,
               "batch_size": self.batch_size}
        if self.compile:
            out["compile"] = True
        if self.precision != "float32":
            out["precision"] = self.precision
        if self.latent_prior:
            out["latent_prior"] = self.latent_prior
        return out if self.lr_final is None else {**out, "lr_final": self.lr_final}


@dataclass
class CandidateResult:
    state: str
    train_loss: float
    val_loss: float
    epochs: int
    wall_s: float
    bundle: Bundle
    epoch_losses: list[float] = field(default_factory=list)
    error: str | None = None  # set when training diverged (non-finite loss)
    fit_score: float | None = None  # neuenh.selection's score on held-out materials, when asked
    fit_score_s: float = 0.0  # the part of wall_s that scoring took

    @property
    def ok(self) -> bool:
        return self.error is None


def slog1p(x: torch.Tensor) -> torch.Tensor:
    """sign(x) log(1 + |x|): log(1 + x) for the non-negative values of a BRDF, and finite with a
    gradient pointing back to zero when a neural module predicts a negative value (where
    log(1 + x) would be NaN for x <= -1)."""
    return torch.sign(x) * torch.log1p(x.abs())


def log_residual(pred: torch.Tensor, target: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
    """Per-sample, per-channel residual (n, 3) of the paper loss: log(1 + f_gt cos_i) - log(1 + f cos_i).
    ``wi`` in the local (ground-truth) frame."""
    cos_i = wi[:, 2:3].clamp_min(0.0)
    return torch.log1p(target * cos_i) - slog1p(pred * cos_i)


def log_l1(pred: torch.Tensor, target: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
    """Per-sample paper loss (n,), averaged over RGB. ``wi`` in the local (ground-truth) frame."""
    return log_residual(pred, target, wi).abs().mean(dim=1)


def predict(model: BRDFModel, materials: MaterialTable, samples: Samples, index: torch.Tensor | slice) -> torch.Tensor:
    """The model's raw f_r (n, 3) for rows ``index`` of ``samples``, each with its material's
    parameters (``BRDFModel.forward_indexed``: what depends on the material alone runs per material)."""
    return model.forward_indexed(samples.wi[index], samples.wo[index], materials.values(), materials.latent,
                                 samples.material[index])


@torch.no_grad()
def evaluate_loss(model: BRDFModel, materials: MaterialTable, samples: Samples, batch_size: int = 200_000) -> float:
    """Mean log-L1 over ``samples``."""
    if len(samples) == 0:
        return float("nan")
    total = 0.0
    for start in range(0, len(samples), batch_size):
        index = slice(start, start + batch_size)
        pred = predict(model, materials, samples, index)
        total += float(log_l1(pred, samples.f_r[index], samples.wi[index]).sum(dtype=torch.float64))
    return total / len(samples)


def batch_loss(model: BRDFModel, materials: MaterialTable, precision: Precision = "float32",
               latent_prior: float = 0.0) -> Callable[..., torch.Tensor]:
    """The mean log-L1 of one batch ``(wi, wo, f_r, material)``: what a training step differentiates
    and ``TrainConfig.compile`` compiles. Every model and state traces into one torch.compile graph
    (tests/neuenh/test_train.py): a graph break costs the compiled step a fifth of its speed (docs/BENCHMARKS.md,
    "The compiled training step"). ``precision`` and ``latent_prior``: see ``TrainConfig``; with a
    prior, each sample also pays ``latent_prior * mean_d (z_d - LATENT_INIT)^2`` of its material's code,
    so a material's codes are pulled in proportion to its samples, as its data term pulls them."""
    low = PRECISIONS[precision]
    products = contextlib.nullcontext if low is None else lambda: torch.autocast("cpu", dtype=low)
    prior = latent_prior > 0 and model.uses_latent

    def loss(wi: torch.Tensor, wo: torch.Tensor, f_r: torch.Tensor, material: torch.Tensor) -> torch.Tensor:
        with products():  # the modules cast their outputs back to the inputs' float32
            pred = model.forward_indexed(wi, wo, materials.values(), materials.latent, material)
        data = log_l1(pred, f_r, wi).mean()
        if not prior:
            return data
        # each material's squared distance from the start, once per material, weighed by its samples here
        distance = (materials.latent - LATENT_INIT).square().mean(dim=1)
        return data + latent_prior * distance[material].mean()

    return loss


# A step differentiates its batch this many rows at a time, the slices' gradients added up: the batch
# mean's gradient, more accurate (float32 sums over fewer rows at once: at 1e5, 4e-6 relative to float64
# against 2e-5 in one pass) and faster where a batch's activations outgrow the CPU's caches (1e5 rows of
# 32 float32 are 12.8 MB a layer): at batch 1e5 the compiled step 1.13-1.33x faster in slices of 10,000
# (8,192-12,500 alike), the eager one 1.15-1.24x (docs/BENCHMARKS.md, "The compiled training step").
STEP_ROWS = 10_000


def backward_in_slices(loss_of: Callable[..., torch.Tensor], wi: torch.Tensor, wo: torch.Tensor,
                       f_r: torch.Tensor, material: torch.Tensor, rows: int = STEP_ROWS) -> float:
    """Accumulate into ``.grad`` the gradient of the batch's mean loss, ``loss_of`` (a ``batch_loss``,
    compiled or not) called on at most ``rows`` rows at a time, each slice's mean weighted by its share
    of the batch; returns that mean. A batch of at most ``rows`` is one call, as it always was."""
    n = len(wi)
    total = 0.0
    for lo in range(0, n, rows):
        part = slice(lo, lo + rows)
        loss = loss_of(wi[part], wo[part], f_r[part], material[part])
        if n > rows:
            loss = loss * (min(rows, n - lo) / n)
        loss.backward()
        total += float(loss.detach())
    return total


@contextlib.contextmanager
def deterministic(enabled: bool = True) -> Iterator[None]:
    """Deterministic algorithms inside the block (restored afterwards): a compiled step's kernels
    otherwise accumulate scatters with atomics across threads, and losses vary in the last bits.
    With one thread those adds run in loop order, so ``train_candidate`` asks for this only with
    more: deterministic kernels cost the compiled step 7 % at batch 4,096 and 14 % at 1e5
    (docs/BENCHMARKS.md, "The compiled training step")."""
    if not enabled:  # nothing to switch; switching imports torch._inductor (~1 s in a fresh process)
        yield
        return
    saved = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(saved)


def train_candidate(
    parent: Bundle, state: str, data: TrainingData, config: TrainConfig, seed: int
) -> CandidateResult:
    """Train the candidate ``state`` grown from ``parent`` (see module docstring)."""
    start = time.perf_counter()
    if parent.materials is None or parent.materials.names != data.names:
        raise ValueError("the parent bundle's materials must be the training data's materials, in order")
    if config.precision == "bfloat16" and not native_bfloat16():
        warnings.warn("train.precision bfloat16 on a CPU without bfloat16 arithmetic (AVX512_BF16 or AMX): its "
                      "products are emulated, and the step is several times slower than in float32",
                      RuntimeWarning, stacklevel=2)
    model = parent.model.enhance(state, seed)
    materials = copy.deepcopy(parent.materials)
    params = [*model.neural.parameters(), *materials.parameters()]
    optimizer = RMSProp(params, lr=config.lr, alpha=config.rmsprop_alpha)
    schedule = None if config.lr_final is None else CosineSchedule(optimizer, config.epochs, config.lr_final)
    generator = torch.Generator().manual_seed(seed)
    train = data.train
    epoch_losses: list[float] = []
    error = None

    loss_of = batch_loss(model, materials, config.precision, config.latent_prior)
    step_loss = torch.compile(loss_of, dynamic=False) if config.compile else loss_of
    with deterministic(config.compile and torch.get_num_threads() > 1):
        for _epoch in range(config.epochs):
            order = torch.randperm(len(train), generator=generator)
            total = 0.0
            for lo in range(0, len(train), config.batch_size):
                index = order[lo : lo + config.batch_size]
                optimizer.zero_grad()
                loss = backward_in_slices(step_loss, train.wi[index], train.wo[index], train.f_r[index],
                                          train.material[index])
                optimizer.step()
                total += loss * len(index)
            epoch_losses.append(total / len(train))
            if schedule is not None:
                schedule.step()
            if not math.isfinite(epoch_losses[-1]):
                error = f"training loss became {epoch_losses[-1]} in epoch {len(epoch_losses)}"
                break
    val_loss = evaluate_loss(model, materials, data.val, config.eval_batch_size)
    if error is None and not math.isfinite(val_loss):
        error = f"validation loss is {val_loss}"
    train_loss = epoch_losses[-1] if epoch_losses else evaluate_loss(model, materials, train)
    bundle = Bundle(model, materials, training={**parent.training, **config.to_json(), "seed": seed},
                    provenance=dict(parent.provenance),
                    metrics={"train_loss": train_loss, "val_loss": val_loss})
    return CandidateResult(
        state=model.state,
        train_loss=train_loss,
        val_loss=val_loss,
        epochs=len(epoch_losses),
        wall_s=time.perf_counter() - start,
        bundle=bundle,
        epoch_losses=epoch_losses,
        error=error,
    )
