"""Which per-material row each sample belongs to, and gathering per-row values to the samples.

The training and fitting paths evaluate many materials at once: parameters come per material (a
*row*), directions per sample. ``BRDFModel.forward_indexed`` and ``NeuralModule.forward_indexed``
take the row of every sample either as an index (n,) — any order — or as a ``RowGrid``: the
samples of row ``r`` are the consecutive run ``r * slots ..`` (``fit.layout.RowLayout``). On a grid,
gathering is a broadcast whose backward is a sum over each row's slots rather than a scatter over
indices: the same values, about a tenth of a fit kernel's time less.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class RowGrid:
    """``rows`` runs of ``slots`` consecutive samples each: sample ``i`` belongs to row ``i // slots``."""

    rows: int
    slots: int


RowIndex = torch.Tensor | RowGrid  # (n,) long: the row of each sample, or a grid of rows


def gather_rows(values: torch.Tensor, rows: RowIndex) -> torch.Tensor:
    """``values`` (m, ...) per row, one per sample: ``values[rows]`` for an index, each row's value
    repeated over its slots for a grid (then m must equal its rows)."""
    if isinstance(rows, RowGrid):
        if values.shape[0] != rows.rows:
            raise ValueError(f"{values.shape[0]} rows of values for a grid of {rows.rows} rows")
        tail = values.shape[1:]
        return values.unsqueeze(1).expand(rows.rows, rows.slots, *tail).reshape(rows.rows * rows.slots, *tail)
    # index_select, not [rows]: its backward accumulates in a fixed order (bit-identical).
    return torch.index_select(values, 0, rows)
