"""Training a ``MaterialEncoder`` for a trained model, its modules frozen.

The encoder learns from the training sources' materials (never RGL): each material's measurements
are drawn once into two *pools* (``MeasurementPools``: Rusinkiewicz-uniform over every azimuth, and
near the mirror direction; a table's rows are both), and every step draws, for a batch of
materials, a *measurement set* of random size (log-uniform in ``set_sizes``) from a random mixture
of the two pools — uniform, mirror, half-and-half or any share between — and, separately, *query*
pairs (half near the mirror, as the report's mirror protocol). The loss is

    L = mean over queries of the paper's log-L1 of the frozen model, with the encoder's parameters
        + regression * mean |unit(encoded) - unit(fitted)|  over analytical parameters and latent

the second term only for materials the model was trained on (its bundle's table: the per-material
parameters the search fitted; unit values so every parameter weighs alike whatever its range).
Adam with the learning rate decaying by a cosine to 1 % of it. The validation error (the same loss
on fixed sets of the held-out materials) is logged every ``eval_every`` steps.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Callable, Sequence

import torch

from .data.samples import Samples
from .encoder import EncoderConfig, MaterialEncoder
from .fit import frozen
from .materials import MaterialTable
from .model import BRDFModel
from .optimizers import Adam, CosineSchedule
from .train import log_l1

__all__ = ["EncoderTrainConfig", "FixedSets", "MeasurementPools", "encoder_loss", "start_losses", "train_encoder"]


@dataclass(frozen=True)
class EncoderTrainConfig:
    steps: int = 4000
    materials_per_step: int = 32
    set_sizes: tuple[int, int] = (1, 2000)  # measurement-set sizes, log-uniform between
    queries: int = 128  # per material and step
    lr: float = 2e-3
    # weight of the pull towards the model's fitted parameters (module doc): for the shipped
    # enhanced GGX, 1.0 gave 0.122 after 600 steps where 0.1 gave 0.132 (held-out training-source
    # materials, docs/BENCHMARKS.md "Amortised starts")
    regression: float = 1.0
    eval_every: int = 250
    seed: int = 0

    def __post_init__(self) -> None:
        lo, hi = self.set_sizes
        if self.steps < 1 or self.materials_per_step < 1 or not 1 <= lo <= hi or self.queries < 1 \
                or self.lr <= 0 or self.regression < 0 or self.eval_every < 1:
            raise ValueError(f"invalid encoder training config {self}")

    def to_json(self) -> dict:
        return {**asdict(self), "set_sizes": list(self.set_sizes)}


class MeasurementPools:
    """Each material's measurements, two ways: ``uniform`` and ``mirror`` (``Samples`` of the same
    materials, each material's rows contiguous). ``draw`` takes sets from them."""

    def __init__(self, uniform: Samples, mirror: Samples):
        if uniform.names != mirror.names:
            raise ValueError("the two pools must hold the same materials, in the same order")
        self.names = uniform.names
        self.pools = (uniform, mirror)
        self.ranges = []
        for pool in self.pools:
            counts = pool.counts()
            if not bool((pool.material[1:] >= pool.material[:-1]).all()) or int(counts.min()) < 1:
                raise ValueError("every material needs measurements, its rows together")
            self.ranges.append((torch.cumsum(counts, 0) - counts, counts))

    @classmethod
    def from_sources(cls, sources: Sequence, uniform: int = 4096, mirror: int = 2048,
                     check: Callable[[], None] | None = None) -> "MeasurementPools":
        """Pools of every material of the job-spec data ``sources`` (``neuenh.data.sources``):
        ``uniform`` pairs Rusinkiewicz-uniform over every azimuth and ``mirror`` pairs near the mirror
        direction per continuous material, a table's (or capture's) rows in both. RGL sources are
        refused: RGL is the validation set, never trained on."""
        uniform_parts, mirror_parts = [], []
        for k, source in enumerate(sources):
            if source.source == "rgl":
                raise ValueError(f"data[{k}] is an RGL source: RGL is the validation set, an encoder never trains on it")
            if "near_mirror" in type(source).model_fields:  # continuous: draws its pairs anywhere
                every = {"every_azimuth": True}
                uniform_parts.append(source.model_copy(update={"samples": uniform, "near_mirror": 0.0, **every}).build(check))
                mirror_parts.append(source.model_copy(update={"samples": mirror, "near_mirror": 1.0, **every}).build(check))
            else:
                rows = source.build(check)
                uniform_parts.append(rows)
                mirror_parts.append(rows)
        return cls(Samples.concat(uniform_parts), Samples.concat(mirror_parts))

    def __len__(self) -> int:
        return len(self.names)

    def subset(self, indices: Sequence[int]) -> "MeasurementPools":
        parts = []
        for pool in self.pools:
            rows = torch.cat([torch.nonzero(pool.material == i).squeeze(1) for i in indices])
            sub = pool.subset(rows)
            remap = torch.full((len(self.names),), -1, dtype=torch.long)
            remap[torch.as_tensor(list(indices))] = torch.arange(len(indices))
            parts.append(Samples(sub.wi, sub.wo, sub.f_r, remap[sub.material], tuple(self.names[i] for i in indices)))
        return MeasurementPools(*parts)

    def draw(self, materials: torch.Tensor, sizes: torch.Tensor, mirror_share: torch.Tensor,
             generator: torch.Generator) -> Samples:
        """A set of ``sizes[k]`` measurements of pool material ``materials[k]`` for each k, each
        measurement from the mirror pool with probability ``mirror_share[k]`` (rows drawn with
        replacement); material indices of the result are k, its names the k-th material's."""
        owner = torch.repeat_interleave(torch.arange(len(materials)), sizes)
        which = torch.rand(len(owner), generator=generator) < mirror_share[owner]
        u = torch.rand(len(owner), generator=generator, dtype=torch.float64)
        out = []
        for pool, (start, count) in zip(self.pools, self.ranges):
            m = materials[owner]
            rows = start[m] + (u * count[m]).long().clamp_max(count[m] - 1)
            out.append(pool.subset(rows))
        pick = which[:, None]
        return Samples(torch.where(pick, out[1].wi, out[0].wi), torch.where(pick, out[1].wo, out[0].wo),
                       torch.where(pick, out[1].f_r, out[0].f_r), owner,
                       tuple(self.names[i] for i in materials.tolist()))


def full_values(model: BRDFModel, raw: dict[str, torch.Tensor], m: int) -> dict[str, torch.Tensor]:
    """Physical values (m, width) of every spec of ``model``: the encoded raw ones, the others at
    their initial value."""
    return {s.name: s.from_raw(raw[s.name]) if s.name in raw else torch.full((m, s.width), s.init)
            for s in model.specs}


def encoder_loss(model: BRDFModel, encoder: MaterialEncoder, measured: Samples, queries: Samples) -> torch.Tensor:
    """Mean log-L1 of ``model`` at ``queries`` with the parameters ``encoder`` gives ``measured``
    (the same materials, in the same order)."""
    raw, latent = encoder(measured)
    values = full_values(model, raw, len(measured.names))
    pred = model.forward_indexed(queries.wi, queries.wo, values, latent, queries.material)
    return log_l1(pred, queries.f_r, queries.wi).mean()


def _regression(encoder: MaterialEncoder, raw: dict[str, torch.Tensor], latent: torch.Tensor,
                target: MaterialTable, rows: torch.Tensor, have: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference in unit values (sigmoid of raw) and in latent, over the materials
    ``have`` marks; ``rows`` index ``target``."""
    if not bool(have.any()):
        return torch.zeros(())
    parts = []
    for name in encoder.outputs:
        want = torch.sigmoid(target.raw[name].detach()[rows[have]])
        parts.append((torch.sigmoid(raw[name][have]) - want).abs().flatten())
    if encoder.latent_dim:
        parts.append((latent[have] - target.latent.detach()[rows[have]]).abs().flatten())
    return torch.cat(parts).mean()


@dataclass(frozen=True)
class FixedSets:
    """Fixed measurement sets and queries of some materials, to compare starts on."""

    measured: Samples
    queries: Samples

    @classmethod
    def of(cls, pools: MeasurementPools, sizes: Sequence[int], queries: int, seed: int) -> "FixedSets":
        """Every material of ``pools`` once per size of ``sizes`` (half near the mirror)."""
        g = torch.Generator().manual_seed(seed)
        materials = torch.arange(len(pools)).repeat(len(sizes))
        size = torch.tensor(sizes).repeat_interleave(len(pools))
        half = torch.full((len(materials),), 0.5)
        return cls(pools.draw(materials, size, half, g),
                   pools.draw(materials, torch.full_like(size, queries), half, g))

    def block(self, k: int, m: int) -> "FixedSets":
        """The sets of the ``k``-th size when ``of`` drew them for ``m`` materials."""
        def rows(samples: Samples) -> Samples:
            keep = torch.nonzero((samples.material >= k * m) & (samples.material < (k + 1) * m)).squeeze(1)
            sub = samples.subset(keep)
            return Samples(sub.wi, sub.wo, sub.f_r, sub.material - k * m, samples.names[k * m:(k + 1) * m])
        return FixedSets(rows(self.measured), rows(self.queries))


@torch.no_grad()
def start_losses(model: BRDFModel, sets: FixedSets, encoder: MaterialEncoder | None,
                 latent_mean: torch.Tensor | None) -> dict[str, float]:
    """Mean log-L1 at the queries of ``sets`` without any fitting, from the paper's start, the
    mean latent code of the training materials (analytical values at their init) and ``encoder``."""
    names, m = sets.measured.names, len(sets.measured.names)
    out = {}
    paper = MaterialTable(model.specs, names, model.latent_dim)
    starts = {"paper": paper}
    if latent_mean is not None:
        starts["mean_latent"] = MaterialTable(model.specs, names, model.latent_dim,
                                              {k: v.detach() for k, v in paper.raw.items()},
                                              latent_mean.reshape(1, -1).expand(m, -1))
    if encoder is not None:
        starts["encoder"] = encoder.encode(sets.measured)
    q = sets.queries
    for label, table in starts.items():
        pred = model.forward_indexed(q.wi, q.wo, table.values(), table.latent, q.material)
        out[label] = float(log_l1(pred, q.f_r, q.wi).double().mean())
    return out


def train_encoder(model: BRDFModel, pools: MeasurementPools, config: EncoderTrainConfig = EncoderTrainConfig(), *,
                  encoder_config: EncoderConfig = EncoderConfig(), fitted: MaterialTable | None = None,
                  validation: FixedSets | None = None, log: Callable[[str], None] | None = None
                  ) -> tuple[MaterialEncoder, list[dict]]:
    """Train an encoder for ``model`` (frozen) on the materials of ``pools`` (module doc);
    ``fitted``: the model's training materials, whose fitted parameters the regression pulls
    towards where names match. Returns the encoder and its history (one row per evaluation)."""
    encoder = MaterialEncoder(model.specs, model.used_specs().names, model.latent_dim, encoder_config,
                              seed=config.seed)
    rows = torch.full((len(pools),), -1, dtype=torch.long)
    if fitted is not None and len(fitted):
        where = {fitted.names[i]: i for i in fitted.coded()}  # a material fitted analytically has no code to learn
        rows = torch.tensor([where.get(name, -1) for name in pools.names])
        known = rows[rows >= 0]
        if len(known):  # start the head at the fitted materials' mean
            with torch.no_grad():
                mean = [fitted.raw[name].detach()[known].mean(0) for name in encoder.outputs]
                encoder.offset.copy_(torch.cat(mean + [fitted.latent.detach()[known].mean(0)]))
    latent_mean = fitted.mean_latent() if fitted is not None else None
    optimizer = Adam(encoder.parameters(), lr=config.lr)
    schedule = CosineSchedule(optimizer, config.steps, config.lr * 0.01)
    g = torch.Generator().manual_seed(config.seed)
    lo, hi = config.set_sizes
    history: list[dict] = []
    start = time.perf_counter()
    running = []
    model.eval()
    with frozen(model):
        for step in range(1, config.steps + 1):
            b = config.materials_per_step
            materials = torch.randint(len(pools), (b,), generator=g)
            sizes = torch.exp(math.log(lo) + (math.log(hi + 1) - math.log(lo)) * torch.rand(b, generator=g)).long()
            sizes = sizes.clamp(lo, hi)
            # the share of each set near the mirror: uniform, mirror, half-and-half, or anything between
            kind = torch.randint(4, (b,), generator=g)
            share = torch.where(kind == 0, 0.0, torch.where(kind == 1, 1.0, torch.where(kind == 2, 0.5,
                                                                                           torch.rand(b, generator=g))))
            measured = pools.draw(materials, sizes, share, g)
            queries = pools.draw(materials, torch.full((b,), config.queries), torch.full((b,), 0.5), g)
            raw, latent = encoder(measured)
            values = full_values(model, raw, b)
            pred = model.forward_indexed(queries.wi, queries.wo, values, latent, queries.material)
            loss = log_l1(pred, queries.f_r, queries.wi).mean()
            total = loss
            if config.regression and fitted is not None:
                rows_b = rows[materials]
                total = total + config.regression * _regression(encoder, raw, latent, fitted, rows_b, rows_b >= 0)
            optimizer.zero_grad()
            total.backward()
            torch.nn.utils.clip_grad_norm_(encoder.parameters(), 1.0)
            optimizer.step()
            schedule.step()
            running.append(float(loss.detach()))
            if step % config.eval_every == 0 or step == config.steps:
                row = {"step": step, "train_log_l1": sum(running) / len(running),
                       "seconds": round(time.perf_counter() - start, 1)}
                running = []
                if validation is not None:
                    row.update({f"val_{k}": v for k, v in start_losses(model, validation, encoder, latent_mean).items()})
                history.append(row)
                if log is not None:
                    log(" ".join(f"{k} {v:.5f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))
    return encoder, history
