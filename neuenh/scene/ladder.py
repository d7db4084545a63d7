"""The ladder of a scene: the models a material may be given, cheapest first, behind one interface.

A :class:`Rung` fits many materials at once and gives back, per material, a :class:`FittedRung`:
its BRDF for rendering (the specialized evaluator, ``neuenh.specialize``), its raw prediction for
the held-out loss, its parameters as plain data, and their size. Two kinds:

* :class:`GraphRung` — a ``BRDFModel`` with frozen module weights (an analytical model, or one
  rung of a searched model: ``neuenh.pretrained.rungs``), fitted by ``fit.fit_materials`` on all
  materials in one batch; its per-material parameters are the ones its state reads at the scene's
  capacity (latent), or at the rung's own (``{model: M, capacity: C}``: with ``auto`` a material may
  carry corrections of the module weights, or be fitted by an analytical model of the same graph);
* :class:`NBRDFRung` — a 6-21-21-3 network per material (Sztrajman et al. 2021), 675 parameters.

``build_ladder(entries)`` turns a scene's ladder (``SceneSpec.ladder``) into rungs. A rung's
*cost* is measured, not assumed: nanoseconds per evaluation of a fitted material's BRDF on this
machine (:func:`measure_cost`, one thread), beside its bytes of per-material parameters.
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import torch

from ..data.directions import sample_directions
from ..data.samples import Samples
from ..encoder import MaterialEncoder
from ..fit import FitOptions, fit_materials, model_for
from ..materials import MaterialParams, MaterialTable
from ..model import BRDFModel
from ..train import log_l1
from .spec import ModelEntry, ladder_source

__all__ = ["FittedRung", "GraphRung", "NBRDFRung", "Rung", "build_ladder", "measure_cost", "rung_brdf",
           "rung_costs"]

Directions = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
BYTES_PER_PARAMETER = 4  # float32, as the exporters store them


@dataclass
class FittedRung:
    """One rung fitted to one material."""

    brdf: Directions  # f_r (n, 3): clipped at 0, zero below either horizon (render, export)
    predict: Directions  # raw f_r (n, 3): what the loss sees
    params: dict[str, Any]  # what the plan stores (a graph rung: MaterialParams.to_json())
    n_params: int
    fit_loss: float
    by_rung_model: bool = True  # False: fitted at an analytical capacity, by an analytical model of its own

    @property
    def param_bytes(self) -> int:
        return self.n_params * BYTES_PER_PARAMETER

    def heldout_log_l1(self, test: Samples) -> float:
        with torch.no_grad():
            return float(log_l1(self.predict(test.wi, test.wo), test.f_r, test.wi).double().mean())


class Rung(ABC):
    """A model of the ladder: ``label`` for people, ``key`` stable for files and resumes."""

    label: str
    key: str
    model_name: str  # the registered model, or "nbrdf"
    state: str | None  # the enhancement state of a graph rung
    shared_weights: int

    @abstractmethod
    def fit(self, samples: Samples, options: FitOptions, seed: int) -> list[FittedRung]:
        """Every material of ``samples`` fitted, in ``samples.names`` order."""

    @abstractmethod
    def brdf_of(self, params: Mapping[str, Sequence[float]]) -> Directions:
        """The BRDF of a material fitted earlier, from its ``FittedRung.params``."""


class GraphRung(Rung):
    """``model`` fitted by ``fit_materials``. Its fits start where ``neuenh fit``'s start: from
    ``trained``, the model's training materials (their mean code, and the training codes that fit a
    material best: ``LatentAdam``); a search's rung, from that round's (``checkpoint.Rung.trained``:
    only their mean for the earlier rungs of a bundle written before stop 57)."""

    def __init__(self, label: str, key: str, model: BRDFModel, trained: MaterialTable | None = None,
                 source: str | None = None, round_index: int | None = None, val_loss: float | None = None,
                 capacity: str | None = None, encoder: MaterialEncoder | None = None):
        self.label, self.key, self.model, self.encoder = label, key, model, encoder  # encoder: one more start
        self.capacity = capacity  # the fit's capacity (FitOptions.capacity); None: the scene's
        self.model_name, self.state, self.shared_weights = model.name, model.state, model.n_weights()
        self.source, self.round = source, round_index  # the shipped model or bundle it is a rung of
        self.val_loss, self.trained = val_loss, trained  # the search's, carried into plans' bundles

    def fit(self, samples: Samples, options: FitOptions, seed: int) -> list[FittedRung]:
        model = self.model
        if self.capacity is not None:
            options = options.replace(capacity=self.capacity)
        result = fit_materials(model, samples, options.protocol_for(model), seed=seed, trained=self.trained,
                               encoder=self.encoder)
        out = []
        for i in range(len(samples.names)):
            own, params = result.material_model(model, i)  # its capacity's model and record

            @torch.no_grad()
            def predict(wi, wo, own=own, params=params):
                return own.unclipped(wi, wo, params)

            out.append(FittedRung(own.specialize(params), predict, params.to_json(), params.n_params,
                                  result.losses[i], by_rung_model=own is model))
        return out

    def brdf_of(self, params):
        params = MaterialParams.from_json(params)
        own = model_for(self.model, params)  # a material fitted at an analytical capacity: its model
        return own.specialize(own.used_params(params))


class NBRDFRung(Rung):
    label, key, model_name, state, shared_weights = "NBRDF (per material)", "nbrdf", "nbrdf", None, 0

    def fit(self, samples: Samples, options: FitOptions, seed: int) -> list[FittedRung]:
        """Adam, ``NBRDFConfig``'s defaults (300 epochs) unless ``options.epochs`` says otherwise."""
        from ..study.nbrdf_fit import NBRDFConfig, fit_nbrdf

        result = fit_nbrdf(samples, NBRDFConfig(epochs=options.epochs) if options.epochs else NBRDFConfig(), seed=seed)
        return [FittedRung(net.evaluate, torch.no_grad()(net.forward), net.state(), net.n_weights(), loss)
                for net, loss in zip(result.networks, result.losses)]

    def brdf_of(self, params):
        from ..study.nbrdf_fit import NBRDFNetwork

        return NBRDFNetwork.from_state(params).evaluate


def build_ladder(entries: Sequence[Any], where: str = "ladder") -> list[Rung]:
    """The scene's ladder entries as rungs, in order: a model name (``ggx``, a shipped model, a bundle
    folder: its final model) or ``nbrdf``, ``{model: MODEL, capacity: C}`` (that model fitted at
    capacity C), or ``{rungs: MODEL}`` (every rung of a searched model). Every problem is a
    ValueError naming the entry."""
    from ..pretrained import load_for_fitting, rungs

    out: list[Rung] = []
    for i, entry in enumerate(entries):
        name = ladder_source(entry)
        try:
            if isinstance(entry, str) and entry == "nbrdf":
                out.append(NBRDFRung())
            elif isinstance(entry, (str, ModelEntry)):
                capacity = getattr(entry, "capacity", None)
                model, trained, encoder = load_for_fitting(name, f"{where}.{i}")
                label, key = (name, name) if capacity is None else \
                    (f"{name} ({capacity} capacity)", f"{name}:{capacity}")
                out.append(GraphRung(label, key, model, trained, source=name, capacity=capacity, encoder=encoder))
            else:
                for r in rungs(name):
                    label = f"{name} r{r.round}" if r.round >= 0 else name
                    out.append(GraphRung(f"{label} {r.model.describe()}", f"{name}@{r.round}:{r.state}", r.model,
                                         r.trained(), source=name, round_index=r.round, val_loss=r.val_loss))
        except ValueError as exc:
            message = str(exc)
            raise ValueError(message if message.startswith(f"{where}.{i}") else f"{where}.{i}: {message}") from None
    keys = [r.key for r in out]
    duplicated = sorted({k for k in keys if keys.count(k) > 1})
    if duplicated:
        raise ValueError(f"{where}: {', '.join(duplicated)} more than once")
    return out


def rung_brdf(fitted: Sequence[FittedRung]) -> Directions:
    """What a rung's cost is measured on: the first of its fitted materials its own model evaluates
    (a material of an adaptive rung fitted at an analytical capacity costs less; the rung stands for
    its model)."""
    return next((f for f in fitted if f.by_rung_model), fitted[0]).brdf


def rung_costs(brdfs: Mapping[str, Directions], rounds: int = 3) -> dict[str, float]:
    """Each rung's cost (``measure_cost``), measured side by side: ``rounds`` rounds over all rungs,
    the fastest of each rung's. Timings taken minutes apart, each after its own rung's fit, differed
    by up to 1.6x for the same model (BENCHMARKS, stop 34); interleaved, a slow spell of the machine
    lands on every rung alike."""
    costs: dict[str, float] = {}
    for _ in range(rounds):
        for key, brdf in brdfs.items():
            costs[key] = min(costs.get(key, math.inf), measure_cost(brdf))
    return costs


@torch.no_grad()
def measure_cost(brdf: Directions, n: int = 65_536, repeats: int = 5) -> float:
    """Nanoseconds per evaluation of ``brdf`` on one thread: the fastest of ``repeats`` timed calls on
    ``n`` Rusinkiewicz-uniform pairs (float32) after a warm-up call (the fastest, not the median: on a
    shared machine other work only ever adds time, and costs measured at different moments are
    compared with each other)."""
    wi, wo = (t.float() for t in sample_directions(n, seed=12345))
    saved = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        brdf(wi, wo)
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            brdf(wi, wo)
            times.append(time.perf_counter() - start)
    finally:
        torch.set_num_threads(saved)
    return min(times) / n * 1e9
