"""Neural modules: the small MLPs that replace a term or an operator, and their configuration.

Paper, Sec. 3 and Fig. 4: a 4-layer fully connected network (hidden widths 16, 32, 16), LeakyReLU
after every layer but the last, Xavier initialisation. Its input depends on what it replaces:

* a node that reads directions: all analytical parameters + latent + ``wi, wo`` (12 + 27 + 6 = 45
  for GGX's D);
* a node that does not: all analytical parameters + latent (39);
* an operator: its two operands, concatenated.

Its output has the width of what it replaces (1 or 3).

Digits of an enhancement state select a *choice* per position: 0 is the original term, digit k >= 1
is ``ModuleConfig.choices[k - 1]`` (the paper's m-ary extension). The default offers one choice,
the paper's module, so states are binary; add choices (e.g. another width) for m-ary searches.
"""

from __future__ import annotations

import contextlib
import zlib
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Iterator

import torch
from torch import nn


@dataclass(frozen=True)
class ModuleConfig:
    """Which neural module each non-zero digit stands for."""

    choices: tuple[tuple[int, ...], ...] = ((16, 32, 16),)
    negative_slope: float = 0.01  # LeakyReLU slope (PyTorch default; the paper does not say)

    def __post_init__(self) -> None:
        if not self.choices:
            raise ValueError("ModuleConfig needs at least one module choice")
        for hidden in self.choices:
            if not hidden or any(int(w) < 1 for w in hidden):
                raise ValueError(f"module hidden widths must be positive, got {hidden}")

    @property
    def digits(self) -> int:
        """m of the m-ary enhancement state: the original term plus one digit per choice."""
        return 1 + len(self.choices)

    def hidden(self, digit: int) -> tuple[int, ...]:
        if not 1 <= digit < self.digits:
            raise ValueError(f"digit {digit} selects no module; this config allows 1..{self.digits - 1}")
        return tuple(self.choices[digit - 1])

    def to_json(self) -> dict:
        return {"choices": [list(c) for c in self.choices], "negative_slope": self.negative_slope}

    @classmethod
    def from_json(cls, data: dict) -> "ModuleConfig":
        return cls(
            choices=tuple(tuple(int(w) for w in c) for c in data["choices"]),
            negative_slope=float(data.get("negative_slope", 0.01)),
        )


def module_seed(seed: int, position: str, digit: int) -> int:
    """A stable per-(seed, position, digit) seed: the same candidate gets the same fresh module in
    every process, and different positions never share an initialisation."""
    return zlib.crc32(f"{seed}:{position}:{digit}".encode()) & 0x7FFFFFFF


class NeuralModule(nn.Module):
    """An MLP ``in -> hidden... -> out`` with LeakyReLU between layers and Xavier init."""

    def __init__(
        self,
        in_features: int,
        out_features: int,
        hidden: tuple[int, ...] = (16, 32, 16),
        negative_slope: float = 0.01,
        generator: torch.Generator | None = None,
    ):
        super().__init__()
        widths = [in_features, *hidden, out_features]
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(widths[:-1], widths[1:]))
        self.negative_slope = negative_slope
        for layer in self.layers:
            nn.init.xavier_uniform_(layer.weight, generator=generator)
            nn.init.zeros_(layer.bias)

    @property
    def in_features(self) -> int:
        return self.layers[0].in_features

    @property
    def out_features(self) -> int:
        return self.layers[-1].out_features

    @property
    def hidden(self) -> tuple[int, ...]:
        return tuple(layer.out_features for layer in self.layers[:-1])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        dtype = x.dtype
        x = x.to(self.layers[0].weight.dtype)
        for layer in self.layers[:-1]:
            x = nn.functional.leaky_relu(layer(x), self.negative_slope)
        return self.layers[-1](x).to(dtype)

    def flops_per_sample(self) -> int:
        """Multiply-adds counted as two FLOPs, activations ignored."""
        return sum(2 * layer.in_features * layer.out_features for layer in self.layers)


# -- running several modules on one input -------------------------------------------------------
# How ``run_modules`` runs several modules that read the same input:
#   "off"         one module after the other (the default: no fused mode measured faster, below);
#   "batched"     first layers as one wide matmul, later layers as one ``baddbmm`` each;
#   "first_layer" first layers as one wide matmul, later layers module by module.
FUSION_MODES = ("off", "batched", "first_layer")
_FUSION: ContextVar[str] = ContextVar("neuenh_module_fusion", default="off")


@contextlib.contextmanager
def fusion(mode: str | bool) -> Iterator[None]:
    """Within the block, ``run_modules`` runs in ``mode`` (``True`` = "batched", ``False`` = "off")."""
    if isinstance(mode, bool):
        mode = "batched" if mode else "off"
    if mode not in FUSION_MODES:
        raise ValueError(f"fusion mode must be one of {FUSION_MODES} or a bool, got {mode!r}")
    token = _FUSION.set(mode)
    try:
        yield
    finally:
        _FUSION.reset(token)


def run_modules(modules: list[NeuralModule], x: torch.Tensor) -> list[torch.Tensor]:
    """Evaluate several modules on the same input ``x``; returns their outputs in order.

    By default ``[m(x) for m in modules]``. Inside ``fusion("batched")`` (or ``fusion(True)``)
    modules are fused when there are several: the first layers run as one wide matmul
    ``(n, in) @ (in, sum of first widths)`` and the later layers as one batched matmul per layer
    (``torch.baddbmm`` over stacked weights) when the modules' later layer shapes and slopes
    agree, else module by module (as always in ``fusion("first_layer")``). The concatenated and
    stacked weights are built from the modules' own parameters at every call
    (``torch.cat``/``torch.stack`` are differentiable), so gradients reach each module's weights;
    outputs and gradients equal the loop's up to float rounding.

    Fusion is off by default because it was not faster where measured (bench/bench_core.py,
    docs/BENCHMARKS.md; 2-core Zen 4 with AVX-512, torch 2.13 CPU, the paper state's F, G, invE at
    batches of 1e4-1e5): the whole enhanced GGX ran at 0.70-0.96x the loop's speed in forward and
    0.85-1.13x in forward+backward when batched (CPU ``baddbmm`` over three tall thin matrices is
    slower than three MKL ``addmm`` calls, and its outputs, above glibc's 32 MB mmap threshold at
    1e5, are page-faulted afresh on every call), and at 0.90-1.05x, i.e. within noise, with the
    first layer fused only. Switch a mode on where a benchmark shows it wins (e.g. another device).
    """
    mode = _FUSION.get()
    if mode == "off" or len(modules) < 2 or not _fusable(modules, x):
        return _run_modules_unfused(modules, x)
    return _run_modules_fused(modules, x, batched=mode == "batched")


def _run_modules_unfused(modules: list[NeuralModule], x: torch.Tensor) -> list[torch.Tensor]:
    """The reference: one module after the other."""
    return [module(x) for module in modules]


def _fusable(modules: list[NeuralModule], x: torch.Tensor) -> bool:
    """All modules read ``x``'s width and keep every parameter in one dtype and device."""
    weight = modules[0].layers[0].weight
    return x.ndim >= 1 and all(
        m.in_features == x.shape[-1]
        and all(p.dtype == weight.dtype and p.device == weight.device for p in m.parameters())
        for m in modules
    )


def _same_later_layers(modules: list[NeuralModule]) -> bool:
    """Whether the layers after the first can run as one batched matmul each."""
    head = modules[0]
    shapes = [tuple(layer.weight.shape) for layer in head.layers[1:]]
    return len(shapes) > 0 and all(
        m.negative_slope == head.negative_slope
        and [tuple(layer.weight.shape) for layer in m.layers[1:]] == shapes
        for m in modules[1:]
    )


def _run_modules_fused(
    modules: list[NeuralModule], x: torch.Tensor, batched: bool = True
) -> list[torch.Tensor]:
    """Fused evaluation (see ``run_modules``); ``batched`` allows ``baddbmm`` for later layers."""
    dtype, lead = x.dtype, x.shape[:-1]
    x = x.to(modules[0].layers[0].weight.dtype).reshape(-1, x.shape[-1])
    first = [m.layers[0] for m in modules]
    weight = torch.cat([layer.weight for layer in first])  # (sum h1, in)
    bias = torch.cat([layer.bias for layer in first])
    h = torch.addmm(bias, x, weight.t())  # (n, sum h1): every module's first layer at once
    if batched and _same_later_layers(modules):
        k, slope = len(modules), modules[0].negative_slope
        h = nn.functional.leaky_relu(h, slope)
        # (n, k * h1) -> (k, n, h1): one contiguous block per module for the batched matmuls.
        h = h.view(h.shape[0], k, first[0].out_features).transpose(0, 1).contiguous()
        last = len(modules[0].layers) - 1
        for i in range(1, last + 1):
            weights = torch.stack([m.layers[i].weight for m in modules]).transpose(1, 2)  # (k, a, b)
            biases = torch.stack([m.layers[i].bias for m in modules]).unsqueeze(1)  # (k, 1, b)
            h = torch.baddbmm(biases, h, weights)
            if i < last:
                h = nn.functional.leaky_relu(h, slope)
        outs = list(h.unbind(0))
    else:  # split the fused first layer, go on module by module
        outs = []
        parts = h.split([layer.out_features for layer in first], dim=1)
        for module, part in zip(modules, parts):
            for layer in module.layers[1:]:
                part = layer(nn.functional.leaky_relu(part, module.negative_slope))
            outs.append(part)
    return [out.reshape(*lead, out.shape[-1]).to(dtype) for out in outs]
