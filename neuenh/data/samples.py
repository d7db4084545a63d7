"""Sample sets: measured (or synthetic) reflectance values of several materials, as flat arrays.

One row per measurement: ``wi, wo`` (local frame, unit), ``f_r`` (RGB, without the cosine) and the
index of its material in ``names``. Training reads these; a split is seeded and reproducible.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol, Sequence

import torch

from .directions import Sampling, sample_directions


class Material(Protocol):
    """What a sample set needs of a material: a name, isotropy and measured samples."""

    name: str
    isotropic: bool

    def samples(self, n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]: ...


@dataclass
class Samples:
    """``n`` measurements of ``len(names)`` materials; tensors are float32 (int64 for material)."""

    wi: torch.Tensor
    wo: torch.Tensor
    f_r: torch.Tensor
    material: torch.Tensor
    names: tuple[str, ...]

    def __post_init__(self) -> None:
        n = self.wi.shape[0]
        for label, t, width in (("wi", self.wi, 3), ("wo", self.wo, 3), ("f_r", self.f_r, 3)):
            if t.ndim != 2 or t.shape != (n, width):
                raise ValueError(f"samples: {label} must have shape ({n}, {width}), got {tuple(t.shape)}")
        if self.material.shape != (n,):
            raise ValueError(f"samples: material must have shape ({n},), got {tuple(self.material.shape)}")
        if n and (int(self.material.min()) < 0 or int(self.material.max()) >= len(self.names)):
            raise ValueError("samples: material indices out of range of names")

    def __len__(self) -> int:
        return self.wi.shape[0]

    def counts(self) -> torch.Tensor:
        """The number of rows of each material, in ``names`` order (int64, zeros included)."""
        return torch.bincount(self.material, minlength=len(self.names))

    def subset(self, index: torch.Tensor) -> "Samples":
        return Samples(self.wi[index], self.wo[index], self.f_r[index], self.material[index], self.names)

    def of_material(self, i: int) -> "Samples":
        return self.subset(torch.nonzero(self.material == i).squeeze(1))

    def select(self, materials: Sequence[int]) -> "Samples":
        """The rows of ``materials`` (indices into ``names``) as a sample set of those materials
        alone, in the given order (rows keep their relative order within each material)."""
        materials = list(materials)
        if len(set(materials)) != len(materials) or any(not 0 <= i < len(self.names) for i in materials):
            raise ValueError(f"samples: cannot select materials {materials} of {len(self.names)}")
        renumber = torch.full((len(self.names),), -1, dtype=torch.long)
        renumber[materials] = torch.arange(len(materials))
        new = renumber[self.material]
        rows = torch.nonzero(new >= 0).squeeze(1)
        rows = rows[torch.argsort(new[rows], stable=True)]
        return Samples(self.wi[rows], self.wo[rows], self.f_r[rows], new[rows],
                       tuple(self.names[i] for i in materials))

    def count_at_most(self, n: int | None) -> int:
        """How many rows ``at_most(n, ...)`` keeps (None: every row)."""
        return len(self) if n is None else int(self.counts().clamp(max=n).sum())

    def at_most(self, n: int, seed: int) -> "Samples":
        """At most ``n`` rows of each material: a seeded random ``n`` of a material that has more,
        every row of the others; rows keep their order. ``self`` when no material has more."""
        if n < 1:
            raise ValueError(f"samples: at_most needs n >= 1, got {n}")
        if len(self) == 0 or int(self.counts().max()) <= n:
            return self
        generator = torch.Generator().manual_seed(seed)
        keep = []
        for i in range(len(self.names)):
            rows = torch.nonzero(self.material == i).squeeze(1)
            keep.append(rows[torch.randperm(len(rows), generator=generator)[:n]] if len(rows) > n else rows)
        return self.subset(torch.cat(keep).sort().values)

    def split(self, val_fraction: float, seed: int) -> tuple["Samples", "Samples"]:
        """Seeded random split into (train, validation); every material keeps its share."""
        if not 0.0 <= val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
        generator = torch.Generator().manual_seed(seed)
        train_idx, val_idx = [], []
        for i in range(len(self.names)):
            rows = torch.nonzero(self.material == i).squeeze(1)
            rows = rows[torch.randperm(len(rows), generator=generator)]
            n_val = int(round(val_fraction * len(rows)))
            val_idx.append(rows[:n_val])
            train_idx.append(rows[n_val:])
        return self.subset(torch.cat(train_idx).sort().values), self.subset(torch.cat(val_idx).sort().values)

    @staticmethod
    def concat(parts: Sequence["Samples"]) -> "Samples":
        names: list[str] = []
        materials = []
        for part in parts:
            materials.append(part.material + len(names))
            names.extend(part.names)
        return Samples(
            torch.cat([p.wi for p in parts]),
            torch.cat([p.wo for p in parts]),
            torch.cat([p.f_r for p in parts]),
            torch.cat(materials),
            tuple(names),
        )


def sample_materials(materials: Sequence[Material], n: int, seed: int,
                     check: Callable[[], None] | None = None, sampling: Sampling | None = None) -> Samples:
    """``n`` samples of each material, seeded per material so adding one changes no other;
    ``check()`` runs before each material (it may raise to abandon the work). ``sampling``: how
    continuous materials draw their pairs (tables have their rows; leave it None for them)."""
    wis, wos, fs, ids = [], [], [], []
    extra = () if sampling is None else (sampling,)
    for i, material in enumerate(materials):
        if check is not None:
            check()
        wi, wo, f = material.samples(n, seed * 100_003 + i, *extra)
        wis.append(wi)
        wos.append(wo)
        fs.append(f)
        ids.append(torch.full((len(wi),), i, dtype=torch.long))
    return Samples(
        torch.cat(wis).float(),
        torch.cat(wos).float(),
        torch.cat(fs).float(),
        torch.cat(ids),
        tuple(m.name for m in materials),
    )


def rusinkiewicz_samples(evaluate, n: int, seed: int, isotropic: bool):
    """Helper for continuous materials: Rusinkiewicz-uniform directions and their values."""
    wi, wo = sample_directions(n, seed=seed, anisotropic=not isotropic)
    return wi, wo, evaluate(wi, wo)


@dataclass
class TrainingData:
    """Training and validation samples of the same materials (same ``names``, same order), and
    optionally ``holdout``: every sample of materials kept out of training altogether (a data
    source's ``holdout``), on which ``neuenh.selection`` scores candidates by fitting them."""

    train: Samples
    val: Samples
    holdout: Samples | None = None

    def __post_init__(self) -> None:
        if self.train.names != self.val.names:
            raise ValueError("training and validation samples must list the same materials")
        if len(self.train) == 0:
            raise ValueError("no training samples")
        if self.holdout is not None:
            shared = sorted(set(self.holdout.names) & set(self.train.names))
            if shared:
                raise ValueError(f"held-out materials {shared} are also training materials")

    @property
    def names(self) -> tuple[str, ...]:
        return self.train.names

    @property
    def nbytes(self) -> int:
        """Bytes of the materialised arrays (wi, wo, f_r and material ids of both parts)."""
        return sum(t.nbytes for part in (self.train, self.val, self.holdout) if part is not None
                   for t in (part.wi, part.wo, part.f_r, part.material))
