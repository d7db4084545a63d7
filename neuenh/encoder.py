"""Amortised starts: an encoder from a material's measurements to its parameters, in one pass.

A fit with frozen modules (``neuenh.fit``) searches a material's analytical parameters and latent
code from a fixed start, and its end point depends on that start. ``MaterialEncoder`` predicts the
parameters instead, from the measurements themselves: a *set* of ``(wi, wo, f_r)`` of any size (one
sample upward) and any sampling (Rusinkiewicz-uniform, half near the mirror, a measured table's
rows), read by a permutation-invariant set network (Zaheer et al. 2017, "Deep Sets"; the attention
pooling of Lee et al. 2019, "Set Transformer", PMA):

* per sample, features of the pair and its value (``sample_features``: the directions, the half
  vector's and the difference angle's cosines, and the value as the paper's loss sees it,
  ``log(1 + f_r cos_i)``, beside ``log(1 + f_r)``) through an MLP;
* per material, the mean of those features and ``heads`` attention-weighted means (a learned score
  per sample, softmax within the material), plus ``log(1 + n)`` so the head knows how much it saw;
* a head MLP to the raw analytical parameters of the model's *used* specs (``ParamSpec.from_raw``
  maps them into range; the others stay at their initial value) and the latent code, each added to
  ``offset`` (the training materials' mean, so an untrained head predicts the average material).

Contract (``encode``):

* one row per material of ``samples.names``, in that order, as a ``MaterialTable`` of the model's
  specs: the start of a fit (``neuenh.fit``) or, on its own, a material without any fitting;
* the same set in any order gives the same result up to float rounding (pooled sums in float64);
* any number of samples per material: 1 works; a material with none gets the empty set's output;
* finite for every finite input: ``f_r`` of 0 or 1e6, grazing and below-horizon directions
  (negative ``f_r`` counts as 0); a non-finite ``f_r`` or direction is an error naming it;
* no gradient reaches the samples; ``forward`` is the differentiable form training uses.

On disk the encoder is tensors (``tensors``/``from_tensors``, safetensors in a bundle) plus the
JSON ``describe()`` returns; training lives in ``neuenh.encoder_training``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Mapping, Sequence

import torch
from torch import nn

from .data.samples import Samples
from .materials import LATENT_INIT, MaterialTable
from .params import _RAW_LIMIT, ParamSpecs

__all__ = ["EncoderConfig", "MaterialEncoder", "N_FEATURES", "sample_features"]

N_FEATURES = 18
# The head's outputs are squashed softly into +-this: raw analytical values beyond +-_RAW_LIMIT
# saturate the sigmoid anyway, and a latent code this far from the trained codes' range (|z| < ~5 in
# the shipped model) would put the modules where they never learned anything.
LATENT_LIMIT = 8.0


@dataclass(frozen=True)
class EncoderConfig:
    width: int = 64        # per-sample feature width (the MLP's layers and the pooled features)
    depth: int = 3         # layers of the per-sample MLP
    heads: int = 4         # attention-pooling heads besides the mean
    head_hidden: int = 128  # hidden width of the head's two hidden layers
    negative_slope: float = 0.01

    def __post_init__(self) -> None:
        if min(self.width, self.depth, self.head_hidden) < 1 or self.heads < 0:
            raise ValueError(f"invalid encoder config {self}")

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> "EncoderConfig":
        fields = cls.__dataclass_fields__
        unknown = sorted(set(data) - set(fields))
        if unknown:
            raise ValueError(f"unknown encoder config keys {unknown}")
        return cls(**{k: (float(v) if k == "negative_slope" else int(v)) for k, v in data.items()})


def sample_features(wi: torch.Tensor, wo: torch.Tensor, f_r: torch.Tensor) -> torch.Tensor:
    """(n, N_FEATURES) float32 features of measurements ``wi, wo`` (n, 3) unit, local frame, and
    ``f_r`` (n, 3) without the cosine. Every term is bounded for finite input: directions and
    cosines lie in [-1, 1]; the values enter through log(1 + x) of their non-negative part."""
    wi, wo, f_r = wi.double(), wo.double(), f_r.double().clamp_min(0.0)
    cos_i, cos_o = wi[:, 2:3], wo[:, 2:3]
    half = wi + wo
    # the half vector; exactly opposite directions (both horizons at once) have none: it stays 0
    half = half / torch.linalg.vector_norm(half, dim=1, keepdim=True).clamp_min(1e-12)
    cos_h = half[:, 2:3]  # Rusinkiewicz's theta_h: how far from the mirror configuration
    cos_d = (wi * half).sum(1, keepdim=True)  # theta_d: the Fresnel and shadowing angle
    seen = torch.log1p(f_r * cos_i.clamp_min(0.0))  # what the paper's loss compares
    value = torch.log1p(f_r)  # the value itself, also where cos_i is ~0
    features = torch.cat([wi, wo, half, cos_h, cos_d, seen, 0.25 * value, cos_i * cos_o], dim=1)
    return features.float()


class MaterialEncoder(nn.Module):
    """Measurements of materials -> their parameters (module doc). ``specs`` are the model's
    parameter specs (every material carries them all), ``outputs`` the names the encoder predicts
    (the model's used specs), ``latent_dim`` the model's latent size (0: none predicted)."""

    def __init__(self, specs: ParamSpecs, outputs: Sequence[str], latent_dim: int,
                 config: EncoderConfig = EncoderConfig(), seed: int = 0):
        super().__init__()
        unknown = [name for name in outputs if name not in specs]
        if unknown:
            raise ValueError(f"encoder outputs {unknown} are not parameters of the model ({list(specs.names)})")
        self.specs, self.config, self.latent_dim = specs, config, latent_dim
        self.record: dict[str, Any] = {}  # how it was trained and measured (plain JSON data)
        self.outputs = tuple(name for name in specs.names if name in set(outputs))  # spec order
        self.widths = [specs[name].width for name in self.outputs] + [latent_dim]
        generator = torch.Generator().manual_seed(seed)
        c = config
        self.per_sample = _mlp([N_FEATURES] + [c.width] * c.depth, c.negative_slope, generator, last_active=True)
        self.score = nn.Linear(c.width, c.heads, bias=False) if c.heads else None
        if self.score is not None:
            nn.init.xavier_uniform_(self.score.weight, generator=generator)
        pooled = c.width * (1 + c.heads) + 1
        self.head = _mlp([pooled, c.head_hidden, c.head_hidden, sum(self.widths)], c.negative_slope, generator)
        with torch.no_grad():
            self.head[-1].weight.mul_(0.1)  # an untrained encoder predicts about ``offset``
        init = [specs[name].to_raw(torch.tensor([specs[name].init] * specs[name].width, dtype=torch.float64)).float()
                for name in self.outputs]
        self.register_buffer("offset", torch.cat(init + [torch.full((latent_dim,), LATENT_INIT)]))

    # -- the set network ---------------------------------------------------------------------
    def pool(self, samples: Samples) -> torch.Tensor:
        """(m, width * (1 + heads) + 1) pooled features per material of ``samples.names``."""
        _check_finite(samples)
        m = len(samples.names)
        features = self.per_sample(sample_features(samples.wi, samples.wo, samples.f_r))
        material = samples.material
        counts = torch.zeros(m, dtype=torch.float64).index_add_(0, material, torch.ones(len(material), dtype=torch.float64))
        # sums in float64: the result depends on the order of the samples only below float32's rounding
        mean = torch.zeros(m, features.shape[1], dtype=torch.float64).index_add_(0, material, features.double())
        parts = [mean / counts.clamp_min(1.0)[:, None]]
        if self.score is not None:
            scores = self.score(features).double()  # (n, heads)
            # softmax within each material, shifted by the material's maximum (an exact, order-free reduction)
            top = torch.full((m, scores.shape[1]), -math.inf, dtype=torch.float64).scatter_reduce(
                0, material[:, None].expand_as(scores), scores, "amax")
            weights = torch.exp(scores - torch.index_select(top, 0, material).detach())
            total = torch.zeros_like(top).index_add_(0, material, weights)
            weights = weights / torch.index_select(total, 0, material)
            for h in range(scores.shape[1]):
                parts.append(torch.zeros_like(parts[0]).index_add_(0, material, weights[:, h:h + 1] * features.double()))
        parts.append(torch.log1p(counts)[:, None] / math.log(1e4))  # how many samples it saw
        return torch.cat(parts, dim=1).float()

    def forward(self, samples: Samples) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """Differentiable prediction: raw analytical values of ``outputs`` ((m, width) each) and the
        latent code (m, latent_dim)."""
        out = self.head(self.pool(samples)) + self.offset
        parts = torch.split(out, self.widths, dim=1)
        raw = {name: _RAW_LIMIT * torch.tanh(part / _RAW_LIMIT) for name, part in zip(self.outputs, parts)}
        return raw, LATENT_LIMIT * torch.tanh(parts[-1] / LATENT_LIMIT)

    @torch.no_grad()
    def encode(self, samples: Samples) -> MaterialTable:
        """The parameters of every material of ``samples`` (module doc: the contract)."""
        raw, latent = self(samples)
        table = MaterialTable(self.specs, samples.names, self.latent_dim)  # the others at their init
        for name, value in raw.items():
            table.raw[name].copy_(value)
        table.latent.copy_(latent)
        return table

    # -- storage -----------------------------------------------------------------------------
    def describe(self) -> dict[str, Any]:
        """The JSON half of the encoder (its tensors are the other)."""
        return {"config": self.config.to_json(), "outputs": list(self.outputs), "latent_dim": self.latent_dim,
                "n_weights": sum(p.numel() for p in self.parameters()), "training": self.record}

    def tensors(self) -> dict[str, torch.Tensor]:
        return {k: v.detach().contiguous() for k, v in self.state_dict().items()}

    @classmethod
    def from_tensors(cls, specs: ParamSpecs, meta: Mapping[str, Any], tensors: Mapping[str, torch.Tensor]
                     ) -> "MaterialEncoder":
        """The encoder ``describe()`` and ``tensors()`` saved; a ValueError names what does not fit."""
        try:
            encoder = cls(specs, list(meta["outputs"]), int(meta["latent_dim"]),
                          EncoderConfig.from_json(meta["config"]))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"encoder description incomplete ({exc})") from None
        expected = set(encoder.state_dict())
        if set(tensors) != expected:
            raise ValueError(f"encoder tensors do not match its description (missing {sorted(expected - set(tensors))},"
                             f" unexpected {sorted(set(tensors) - expected)})")
        try:
            encoder.load_state_dict(dict(tensors), strict=True)
        except RuntimeError as exc:
            raise ValueError(f"encoder tensors: {exc}") from None
        if not all(torch.isfinite(t).all() for t in tensors.values()):
            raise ValueError("encoder tensors hold non-finite values")
        encoder.record = dict(meta.get("training") or {})
        return encoder


def _mlp(widths: Sequence[int], slope: float, generator: torch.Generator, last_active: bool = False) -> nn.Sequential:
    """Linear layers with LeakyReLU between them (and after the last if ``last_active``), Xavier init."""
    layers: list[nn.Module] = []
    for k, (a, b) in enumerate(zip(widths[:-1], widths[1:])):
        linear = nn.Linear(a, b)
        nn.init.xavier_uniform_(linear.weight, generator=generator)
        nn.init.zeros_(linear.bias)
        layers.append(linear)
        if last_active or k < len(widths) - 2:
            layers.append(nn.LeakyReLU(slope))
    return nn.Sequential(*layers)


def _check_finite(samples: Samples) -> None:
    for label, t in (("wi", samples.wi), ("wo", samples.wo), ("f_r", samples.f_r)):
        if not torch.isfinite(t).all():
            rows = torch.nonzero(~torch.isfinite(t).all(1)).squeeze(1)[:5].tolist()
            raise ValueError(f"measurements hold non-finite {label} (rows {rows}); the encoder needs finite values")
