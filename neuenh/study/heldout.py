"""Held-out evaluation: fit a material on some of its samples, measure the fitted model on others.

The metric is the paper's loss, ``train.log_l1``, averaged per material over samples that took no
part in the fit (issue 6: "fit each model per material on part of the samples and measure on the
rest"):

* :func:`heldout_log_l1` — per material mean log-L1 of a fitted model on held-out ``Samples``;
* :func:`predict_f_r` — the fitted model's ``f_r`` at held-out directions (what
  ``neuenh fit --predictions`` writes, :func:`write_predictions`), so anyone can compute their own
  metric;
* :func:`fit_and_evaluate` — one measured material (``neuenh.data.measured.load_measured``): draw a
  fit set and a test set, fit with ``fit.fit_materials``, report fit loss, held-out loss, time and
  parameters.

**Fit and test sets** (:func:`draw_fit_test`). For a *table* (a material with stored rows and no
continuous ``evaluate``, e.g. ``TableMaterial``) the rows are split by one seeded permutation:
``n_fit`` rows to fit, the next ``n_test`` (default: all the rest) to test — the two sets are
*disjoint* rows. For a *continuous* source (RGL, MERL, NBRDF, analytical: it has ``evaluate``) the
two sets are *independent draws* of ``material.samples`` with two different seeds (``2 seed`` and
``2 seed + 1``): Rusinkiewicz-uniform directions, so they share no direction pair almost surely,
but disjointness is not enforced.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from ..data.samples import Samples
from ..data.table import savez
from ..files import atomic_write
from ..data.directions import sample_directions
from ..fit import FitOptions, FitResult, fit_materials, losses_at_own_capacity, material_model
from ..materials import MaterialTable
from ..model import BRDFModel

__all__ = ["draw_fit_test", "draw_measured", "fit_and_evaluate", "heldout_log_l1", "predict_f_r", "split_rows",
           "write_predictions"]



def _check_names(materials: MaterialTable, samples: Samples) -> None:
    if tuple(samples.names) != tuple(materials.names):
        raise ValueError(f"held-out samples list materials {list(samples.names)}, the fitted parameters "
                         f"{list(materials.names)}; they must be the same, in the same order")


def heldout_log_l1(model: BRDFModel, fitted: FitResult | MaterialTable, samples: Samples) -> list[float]:
    """Mean log-L1 of each material (``materials.names`` order) over its held-out ``samples``.

    Exactly ``fit.losses_at_own_capacity`` — the training loss ``train.log_l1`` on the raw model
    output, float64 accumulation, NaN for a material without samples, each material at the capacity
    and with the corrections its record carries (a ``FitResult``'s table or a bundle's alike) —
    after checking that ``samples`` names the same materials in the same order (its material indices
    index ``materials``). The samples must not have been used to fit them; that is the caller's
    responsibility.
    """
    materials = fitted.materials if isinstance(fitted, FitResult) else fitted
    _check_names(materials, samples)
    return losses_at_own_capacity(model, materials, samples)


@torch.no_grad()
def predict_f_r(model: BRDFModel, fitted: FitResult | MaterialTable, samples: Samples) -> torch.Tensor:
    """The fitted model's ``f_r`` (n, 3), without the cosine, at every row of ``samples``, each
    with its material's fitted record at its own capacity: what ``own.evaluate(wi, wo, params)``
    returns for ``own, params = fit.material_model(model, materials, i)``, computed by each
    material's specialized evaluator (``BRDFModel.specialize``). (The
    loss sees the value before clipping at zero; the two differ only where an enhanced model's
    module predicts a negative value.)"""
    materials = fitted.materials if isinstance(fitted, FitResult) else fitted
    _check_names(materials, samples)
    out = torch.zeros(len(samples), 3)
    for i in torch.unique(samples.material).tolist():
        rows = torch.nonzero(samples.material == i).squeeze(1)
        own, params = material_model(model, materials, i)
        out[rows] = own.specialize(params)(samples.wi[rows], samples.wo[rows]).float()
    return out


def write_predictions(path: str | os.PathLike, samples: Samples, f_r: torch.Tensor) -> Path:
    """Write predictions at the directions of ``samples`` to ``path`` (``.npz``), atomically.

    Arrays: ``wi``, ``wo``, ``f_r`` (n, 3) float32; ``material`` (n,) int64, the row's index into
    ``material_names`` (unicode). ``neuenh.data.table.read_table`` reads the file as a table (it
    ignores the extra arrays) — meaningful as one material's table when it holds a single material.
    """
    path = Path(path)
    if f_r.shape != samples.wi.shape:
        raise ValueError(f"predictions have shape {tuple(f_r.shape)}, the samples {tuple(samples.wi.shape)}")
    arrays = {
        "wi": samples.wi.detach().float().numpy(),
        "wo": samples.wo.detach().float().numpy(),
        "f_r": f_r.detach().float().numpy(),
        "material": samples.material.detach().long().numpy(),
        "material_names": np.array(samples.names, dtype=str),
    }
    atomic_write(path, lambda tmp: savez(tmp, arrays))
    return path


def split_rows(n_rows: int, n_fit: int, n_test: int | None, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Disjoint sorted row indices (fit, test) from one seeded permutation of ``range(n_rows)``:
    the first ``n_fit`` to fit, the next ``n_test`` (``None``: all the rest) to test."""
    if n_test is None:
        n_test = n_rows - n_fit
    if n_fit < 1 or n_test < 1 or n_fit + n_test > n_rows:
        raise ValueError(f"cannot split {n_rows} rows into {n_fit} to fit and {n_test} to test "
                         "(both at least 1, together at most the table's rows)")
    order = torch.randperm(n_rows, generator=torch.Generator().manual_seed(seed))
    return order[:n_fit].sort().values, order[n_fit:n_fit + n_test].sort().values


def _samples(name: str, wi, wo, f_r) -> Samples:
    wi, wo, f_r = (torch.as_tensor(t).float() for t in (wi, wo, f_r))
    return Samples(wi, wo, f_r, torch.zeros(len(wi), dtype=torch.long), (name,))


def _every_azimuth(material, n: int, seed: int, near_mirror: float = 0.0):
    wi, wo = sample_directions(n, seed=seed, anisotropic=True, near_mirror=near_mirror)
    with torch.no_grad():
        return wi, wo, material.evaluate(wi, wo)


def draw_fit_test(material, n_fit: int, n_test: int | None, seed: int,
                  near_mirror: float = 0.0) -> tuple[Samples, Samples, str]:
    """``(fit, test, split)`` samples of one measured material, see the module doc; ``split`` is
    ``"disjoint rows"`` (tables) or ``"independent draws"`` (continuous sources, where ``n_test``
    is required). ``near_mirror``: the share of a continuous source's pairs (fit and test alike)
    drawn near the mirror direction (``data.directions.sample_directions``); tables have their rows."""
    if callable(getattr(material, "evaluate", None)):
        if n_test is None:
            raise ValueError(f"{material.name}: a continuous source needs the number of test samples")
        if n_fit < 1 or n_test < 1:
            raise ValueError(f"need at least 1 fit and 1 test sample, got {n_fit} and {n_test}")
        fit = _samples(material.name, *_every_azimuth(material, n_fit, 2 * seed, near_mirror))
        test = _samples(material.name, *_every_azimuth(material, n_test, 2 * seed + 1, near_mirror))
        return fit, test, "independent draws"
    table = getattr(material, "table", None)
    if not isinstance(table, Samples):
        raise ValueError(f"{getattr(material, 'name', material)!r}: neither a continuous source "
                         "(with evaluate) nor a table of stored samples")
    fit_rows, test_rows = split_rows(len(table), n_fit, n_test, seed)
    fit = _samples(material.name, table.wi[fit_rows], table.wo[fit_rows], table.f_r[fit_rows])
    test = _samples(material.name, table.wi[test_rows], table.wo[test_rows], table.f_r[test_rows])
    return fit, test, "disjoint rows"


def draw_measured(path: str | os.PathLike, samples: int, near_mirror: float, seed: int,
                  test_samples: int | None = None, name: str | None = None) -> tuple[Samples, Samples | None]:
    """(fit, held-out or None) ``Samples`` drawn from the measured file at ``path`` (an RGL or MERL
    file, ``data.measured.load_measured``; ``name`` its material's name, default the file's stem) by
    ``draw_fit_test``: how ``neuenh fit``, ``neuenh-client fit`` and ``POST /v1/jobs/{id}/fit`` draw.
    Without ``test_samples`` one held-out pair is drawn and dropped: the fit's pairs are the same either way."""
    from ..data.measured import load_measured

    fit, test, _ = draw_fit_test(load_measured(path, name), samples, test_samples or 1, seed, near_mirror)
    return fit, (test if test_samples else None)


def fit_and_evaluate(model: BRDFModel, material, n_fit: int, n_test: int | None = None, seed: int = 0,
                     options: FitOptions = FitOptions(), trained: MaterialTable | None = None) -> dict:
    """Fit one measured material with ``model`` (module weights frozen; ``options`` name the fit
    protocol, ``fit.FitOptions``; ``trained``: its training materials, see ``fit.fit_materials``)
    on ``n_fit`` samples and measure it on ``n_test`` others (see :func:`draw_fit_test`). Returns
    plain data::

        {"name", "model", "state", "split", "seed", "n_fit", "n_test", "protocol",
         "fit_loss",        # mean log-L1 on the fit set after fitting
         "heldout_log_l1",  # mean log-L1 on the test set
         "fit_s",           # wall time of the fit (drawing and evaluation excluded)
         "params"}          # fitted parameters, as in ``neuenh fit --json``
    """
    fit, test, split = draw_fit_test(material, n_fit, n_test, seed)
    result = fit_materials(model, fit, options.protocol_for(model), seed=seed, trained=trained)
    (heldout,) = heldout_log_l1(model, result, test)
    (entry,) = result.report(model, fit)["materials"]
    return {
        "name": material.name, "model": model.name, "state": model.state, "split": split, "seed": seed,
        "n_fit": len(fit), "n_test": len(test), "protocol": result.protocol,
        "fit_loss": result.losses[0], "heldout_log_l1": heldout, "fit_s": result.wall_s,
        "params": entry["params"],
    }
