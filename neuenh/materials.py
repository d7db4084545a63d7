"""Per-material parameters: the analytical parameters (as raw optimisation variables) and the
latent (neural) parameters of every material a model is trained on or fitted to.

Raw values map to physical ones through the specs' constrained mapping (``params.ParamSpec``), so
they never leave their valid ranges. Latent parameters are unconstrained and start at 0.5
(paper Sec. 4.3, after Fan et al. 2022).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import torch
from torch import nn

from .params import ParamSpecs

LATENT_INIT = 0.5


class MaterialTable(nn.Module):
    """Parameters of ``len(names)`` materials: ``raw[name]`` (m, width) and ``latent`` (m, L)."""

    def __init__(
        self,
        specs: ParamSpecs,
        names: Sequence[str],
        latent_dim: int,
        raw: Mapping[str, torch.Tensor] | None = None,
        latent: torch.Tensor | None = None,
    ):
        super().__init__()
        self.specs = specs
        self.names = tuple(names)
        m = len(self.names)
        if raw is None:
            raw = {
                s.name: s.to_raw(torch.full((m, s.width), s.init, dtype=torch.float64)).float()
                for s in specs
            }
        if latent is None:
            latent = torch.full((m, latent_dim), LATENT_INIT)
        if set(raw) != set(specs.names):
            raise ValueError(f"material parameters {sorted(raw)} do not match {list(specs.names)}")
        self.raw = nn.ParameterDict(
            {s.name: nn.Parameter(_checked(raw[s.name], (m, s.width), s.name)) for s in specs}
        )
        self.latent = nn.Parameter(_checked(latent, (m, latent_dim), "latent"))

    @property
    def latent_dim(self) -> int:
        return self.latent.shape[1]

    def __len__(self) -> int:
        return len(self.names)

    def values(self) -> dict[str, torch.Tensor]:
        """Physical values, (m, width) each."""
        return {s.name: s.from_raw(self.raw[s.name]) for s in self.specs}

    def gather(self, material: torch.Tensor) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """Per-sample physical values and latent for material indices ``material`` (n,)."""
        # index_select, not v[material]: the backward of advanced indexing accumulates with a
        # thread-order-dependent sum on CPU, which would break bit-identical training.
        values = {name: torch.index_select(v, 0, material) for name, v in self.values().items()}
        return values, torch.index_select(self.latent, 0, material)

    def subset(self, indices: Sequence[int]) -> "MaterialTable":
        index = torch.as_tensor(list(indices), dtype=torch.long)
        return MaterialTable(
            self.specs,
            [self.names[i] for i in index.tolist()],
            self.latent_dim,
            {k: v.detach()[index].clone() for k, v in self.raw.items()},
            self.latent.detach()[index].clone(),
        )

    def tensors(self) -> dict[str, torch.Tensor]:
        """Flat name -> tensor mapping for safetensors."""
        out = {f"raw.{k}": v.detach().contiguous() for k, v in self.raw.items()}
        out["latent"] = self.latent.detach().contiguous()
        return out

    @classmethod
    def from_tensors(
        cls, specs: ParamSpecs, names: Sequence[str], tensors: Mapping[str, torch.Tensor]
    ) -> "MaterialTable":
        raw = {k[len("raw."):]: v for k, v in tensors.items() if k.startswith("raw.")}
        if "latent" not in tensors:
            raise ValueError("material parameters lack 'latent'")
        latent = tensors["latent"]
        return cls(specs, names, latent.shape[1], raw, latent)

    def as_params(self, index: int) -> dict[str, torch.Tensor]:
        """One material's parameters in the form ``BRDFModel.evaluate`` takes."""
        values = {k: v[index].detach() for k, v in self.values().items()}
        values["latent"] = self.latent[index].detach()
        return values


def _checked(t: torch.Tensor, shape: tuple[int, int], name: str) -> torch.Tensor:
    t = torch.as_tensor(t, dtype=torch.float32).detach().clone()
    if tuple(t.shape) != shape:
        raise ValueError(f"material parameter {name!r} must have shape {shape}, got {tuple(t.shape)}")
    if not torch.isfinite(t).all():
        raise ValueError(f"material parameter {name!r} has non-finite values")
    return t
