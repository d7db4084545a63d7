"""Rows of a fit laid out side by side: every row one material's problem over a fixed grid of sample slots.

A fit solves many small independent problems at once — every material, every start, every
cross-validation fold, every capacity and prior strength is a *row* with its own parameters. The
rows share one batch (``RowLayout``): ``rows × slots`` samples, row ``r``'s samples at flat
positions ``r * slots ..``, each row's material's samples in its first slots and the rest padded
(a copy of a real sample, weight 0). Each row carries two sample weights: ``train`` (what it is
fitted to) and ``val`` (what it is scored on: a held-out fold; zero when it has none). Rows of the
same material share their directions, so a fold is a weight mask, not another copy of the data.

A regular grid makes a row's sum a reshape (no scatter), lets per-row module weights run as one
batched matrix product (``kernel``), and splits into minibatches along the slots.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import torch

from ..data.samples import Samples
from ..rows import RowGrid


@dataclass(frozen=True)
class RowLayout:
    """``rows`` problems over ``slots`` sample slots each (module doc)."""

    wi: torch.Tensor  # (rows * slots, 3) float32, local frame
    wo: torch.Tensor  # (rows * slots, 3)
    f_r: torch.Tensor  # (rows * slots, 3) the target values
    train: torch.Tensor  # (rows, slots) float32 weight of each slot in the row's fit loss
    val: torch.Tensor  # (rows, slots) float32 weight in the row's validation loss (zeros: none)
    material: torch.Tensor  # (rows,) long: the material (index into the samples' names) of each row

    @property
    def rows(self) -> int:
        return self.train.shape[0]

    @property
    def slots(self) -> int:
        return self.train.shape[1]

    @property
    def grid(self) -> RowGrid:
        """The row of every flat sample position: ``rows`` runs of ``slots``."""
        return RowGrid(self.rows, self.slots)

    def select(self, rows: torch.Tensor | Sequence[int]) -> "RowLayout":
        """The layout of the given rows, in that order."""
        rows = torch.as_tensor(rows, dtype=torch.long)
        flat = (rows[:, None] * self.slots + torch.arange(self.slots)).reshape(-1)
        return RowLayout(self.wi[flat], self.wo[flat], self.f_r[flat], self.train[rows], self.val[rows],
                         self.material[rows])

    def chunk(self, lo: int, hi: int) -> "RowLayout":
        """Slots ``lo..hi`` of every row: a minibatch along the samples."""
        width = hi - lo
        flat = (torch.arange(self.rows)[:, None] * self.slots + torch.arange(lo, hi)).reshape(-1)
        return RowLayout(self.wi[flat], self.wo[flat], self.f_r[flat], self.train[:, lo:hi].contiguous(),
                         self.val[:, lo:hi].contiguous(), self.material) if width < self.slots else self

    def windows(self, lows: Sequence[int], width: int) -> "RowLayout":
        """Every row once per entry of ``lows``, block ``k`` (rows ``k * rows ..``) its slots
        ``lows[k] .. lows[k] + width``: another subset of every row in each block."""
        if any(lo < 0 or lo + width > self.slots for lo in lows) or width < 1:
            raise ValueError(f"windows {list(lows)} of {width} slots do not fit in {self.slots} slots")
        rows = torch.arange(self.rows).repeat(len(lows))
        slots = torch.tensor(lows, dtype=torch.long).repeat_interleave(self.rows)[:, None] + torch.arange(width)
        flat = (rows[:, None] * self.slots + slots).reshape(-1)
        return RowLayout(self.wi[flat], self.wo[flat], self.f_r[flat], self.train[rows[:, None], slots],
                         self.val[rows[:, None], slots], self.material[rows])

    def with_targets(self, f_r: torch.Tensor) -> "RowLayout":
        """The same rows and weights fitted to other values (e.g. another model's predictions)."""
        return RowLayout(self.wi, self.wo, f_r.reshape(self.f_r.shape), self.train, self.val, self.material)

    def minibatches(self, size: int, generator: torch.Generator | None) -> list["RowLayout"]:
        """Contiguous slot ranges of about ``size`` slots covering every slot once (one epoch); the
        slots' order is a fixed shuffle made by ``padded``, so a range is a random sample."""
        if size >= self.slots:
            return [self]
        count = -(-self.slots // size)
        bounds = [round(i * self.slots / count) for i in range(count + 1)]
        order = list(range(count))
        if generator is not None:
            order = torch.randperm(count, generator=generator).tolist()
        return [self.chunk(bounds[i], bounds[i + 1]) for i in order]


def padded(samples: Samples, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each material's samples in a row of ``slots`` (the largest count), in a seeded random order,
    padded with copies of its first sample: ``wi, wo, f_r`` (m, slots, 3) and ``valid`` (m, slots)
    bool. The shuffle makes any range of slots a random subset (minibatches, folds)."""
    m = len(samples.names)
    counts = samples.counts()
    if int(counts.min()) == 0:
        empty = [samples.names[i] for i in range(m) if counts[i] == 0]
        raise ValueError(f"no samples to fit for material(s) {', '.join(empty)}")
    slots = int(counts.max())
    generator = torch.Generator().manual_seed(seed)
    index = torch.empty(m, slots, dtype=torch.long)
    valid = torch.zeros(m, slots, dtype=torch.bool)
    for i in range(m):
        rows = torch.nonzero(samples.material == i).squeeze(1)
        rows = rows[torch.randperm(len(rows), generator=generator)]
        index[i, : len(rows)] = rows
        index[i, len(rows):] = rows[0]
        valid[i, : len(rows)] = True
    return samples.wi[index], samples.wo[index], samples.f_r[index], valid


def compacted(wi: torch.Tensor, wo: torch.Tensor, f_r: torch.Tensor, keep: torch.Tensor
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rows of ``padded``'s arrays (rows, slots, 3) narrowed to the slots ``keep`` (rows, slots) bool
    marks: each row's kept slots moved to its front in their order, the grid as wide as the row
    with the most, padded with copies of the row's first kept slot. Returns ``wi, wo, f_r`` and
    ``valid`` (rows, width) bool. A fit of a subset then costs what its samples cost, not the
    whole grid (a fold's other samples: two thirds of the slots at three folds)."""
    counts = keep.sum(1)
    if int(counts.min()) == 0:
        raise ValueError("every row must keep at least one slot")
    width = int(counts.max())
    order = torch.argsort((~keep).to(torch.uint8), dim=1, stable=True)[:, :width]  # kept slots first, in order
    valid = torch.arange(width)[None, :] < counts[:, None]
    order = torch.where(valid, order, order[:, :1])
    gather = lambda t: torch.gather(t, 1, order[..., None].expand(-1, -1, t.shape[-1]))
    return gather(wi), gather(wo), gather(f_r), valid


def fold_masks(valid: torch.Tensor, folds: int) -> torch.Tensor:
    """(folds, m, slots) bool: fold ``k`` of each material holds every ``folds``-th of its valid
    slots starting at ``k`` (slots are already shuffled, so folds are random and balanced)."""
    position = valid.long().cumsum(1) - 1  # the rank of each valid slot within its material
    return torch.stack([valid & (position % folds == k) for k in range(folds)])


def layout_rows(wi: torch.Tensor, wo: torch.Tensor, f_r: torch.Tensor, material: torch.Tensor,
                train: torch.Tensor, val: torch.Tensor) -> RowLayout:
    """A layout of rows over the padded per-material arrays of ``padded``: row ``r`` fits material
    ``material[r]`` with slot weights ``train[r]`` and is scored with ``val[r]`` (both (rows, slots))."""
    return RowLayout(wi[material].reshape(-1, 3), wo[material].reshape(-1, 3), f_r[material].reshape(-1, 3),
                     train.float(), val.float(), material)
