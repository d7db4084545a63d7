"""Neural modules: the small MLPs that replace a term or an operator, and their configuration.

Paper, Sec. 3 and Fig. 4: a 4-layer fully connected network (hidden widths 16, 32, 16), LeakyReLU
after every layer but the last, Xavier initialisation. Its input depends on what it replaces:

* a node that reads directions: all analytical parameters + latent + ``wi, wo`` (12 + 27 + 6 = 45
  for GGX's D);
* a node that does not: all analytical parameters + latent (39);
* an operator: its two operands, concatenated.

Its output has the width of what it replaces (1 or 3).

Digits of an enhancement state select a *choice* per position: 0 is the original term, digit k >= 1
is ``ModuleConfig.choices[k - 1]`` (the paper's m-ary extension; ``ModuleConfig`` lives with the state
encoding in ``neuenh.graph`` and is imported from here too). The default offers one choice,
the paper's module, so states are binary; add choices (e.g. another width) for m-ary searches.
"""

from __future__ import annotations

import zlib

import torch
from torch import nn

from .graph import ModuleConfig  # (the digits' meaning; re-exported: what a module of a digit is)
from .rows import RowIndex, gather_rows


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
            # In place: the layer's fresh output is not needed by its own backward (saves a pass
            # over the widest tensors).
            x = nn.functional.leaky_relu(layer(x), self.negative_slope, inplace=True)
        return self.layers[-1](x).to(dtype)

    def forward_indexed(self, per_material: torch.Tensor, per_sample: torch.Tensor | None,
                        material: RowIndex) -> torch.Tensor:
        """``forward(cat([per_material[material], per_sample]))`` without building that input:
        the first layer's per-material part ``b1 + W1[:, :P] @ per_material`` is computed once per
        material (m rows) and gathered per sample, so each sample pays only for its own inputs.

        ``per_material`` (m, P); ``per_sample`` (n, Q) or None when the module reads nothing
        else (then the whole module runs on the m rows and its output is gathered); ``material``
        the row of each sample (``rows.RowIndex``)."""
        first = self.layers[0]
        dtype = per_material.dtype
        per_material = per_material.to(first.weight.dtype)
        k = per_material.shape[1]
        if per_sample is None:
            return gather_rows(self.forward(per_material), material).to(dtype)
        x = gather_rows(torch.addmm(first.bias, per_material, first.weight[:, :k].t()), material)
        x = torch.addmm(x, per_sample.to(first.weight.dtype), first.weight[:, k:].t())
        for layer in self.layers[1:]:
            x = layer(nn.functional.leaky_relu(x, self.negative_slope, inplace=True))
        return x.to(dtype)

    def flops_per_sample(self) -> int:
        """Multiply-adds counted as two FLOPs, activations ignored."""
        return sum(2 * layer.in_features * layer.out_features for layer in self.layers)
