"""A table of materials at random parameters: the fit kernel's tests evaluate rows away from any start."""

import torch

from neuenh.materials import MaterialTable


def random_table(model, names, seed: int) -> MaterialTable:
    """``names``' rows of ``model``: latent codes moved by 0.3 and raw analytical values by 0.5 standard
    normal steps from the paper's start (seeded)."""
    g = torch.Generator().manual_seed(seed)
    table = MaterialTable(model.specs, names, model.latent_dim)
    with torch.no_grad():
        table.latent.add_(0.3 * torch.randn(table.latent.shape, generator=g))
        for raw in table.raw.values():
            raw.add_(0.5 * torch.randn(raw.shape, generator=g))
    return table
