"""Data efficiency: held-out error against the number of fit samples, under two protocols.

The paper's argument for a shared model is a prior: with few measurements of a new material, a
model that learned from many materials should beat a network fitted from scratch. This measures it:
for each material, each *protocol* and each fit-set size ``n`` (``SIZES``), every contender is
fitted on ``n`` measurements and tested on the same ``n_test`` others (``heldout.draw_fit_test``:
the test set does not depend on ``n``), and the held-out log-L1 is reported over all test pairs and
split into pairs *near* the mirror direction (half vector within ``MIRROR_DEG`` of the normal) and
*away* from it, where all models differ least.

Protocols (the share of fit and test pairs drawn near the mirror direction):

* ``uniform`` — uniform in the four Rusinkiewicz angles (the main study's protocol);
* ``mirror`` — half of them near the mirror direction, the way
  ``../shared/data/rgl/reference_values.npz`` draws its pairs: what renders of glossy materials see.

``crossover`` summarises a curve: the largest size at which the enhanced model is ahead of NBRDF on
at least a given number of materials.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass
from typing import Iterable, Sequence

import torch

from ..data.directions import near_mirror_mask
from ..train import log_l1
from .contenders import Contender
from .heldout import draw_fit_test

__all__ = ["CurvePoint", "PROTOCOLS", "SIZES", "crossover", "measure_curve", "medians", "wins"]

PROTOCOLS = {"uniform": 0.0, "mirror": 0.5}  # protocol -> share of pairs near the mirror direction
SIZES = (100, 300, 1000, 3000, 10_000)


@dataclass(frozen=True)
class CurvePoint:
    material: str
    protocol: str
    n_fit: int
    contender: str
    heldout_log_l1: float
    near: float  # over the test pairs near the mirror direction
    away: float  # over the others
    fit_s: float
    params_per_material: int = 0  # at the capacity the fit chose (``contenders.FittedMaterial``)
    capacity: str | None = None  # the fit's capacity (a model with modules)

    def row(self) -> dict:
        return asdict(self)


def measure_curve(material, contenders: Sequence[Contender], sizes: Iterable[int] = SIZES,
                  protocols: Iterable[str] = tuple(PROTOCOLS), n_test: int = 10_000,
                  seed: int = 0) -> list[CurvePoint]:
    """Every contender fitted at every size under every protocol (module doc); ``material`` is a
    continuous measured source (RGL, MERL, NBRDF, analytical)."""
    out = []
    for protocol in protocols:
        share = PROTOCOLS[protocol]
        for n in sizes:
            fit, test, _ = draw_fit_test(material, n, n_test, seed, near_mirror=share)
            near = near_mirror_mask(test.wi.double(), test.wo.double())
            for contender in contenders:
                start = time.perf_counter()
                fitted = contender.fit(fit, seed=seed)
                fit_s = time.perf_counter() - start
                with torch.no_grad():
                    loss = log_l1(fitted.predict(test.wi, test.wo), test.f_r, test.wi).double()
                out.append(CurvePoint(material.name, protocol, n, contender.name, float(loss.mean()),
                                      float(loss[near].mean()) if near.any() else float("nan"),
                                      float(loss[~near].mean()) if (~near).any() else float("nan"), fit_s,
                                      fitted.params_per_material, fitted.capacity))
    return out


def medians(points: Sequence[CurvePoint], protocol: str, field: str = "heldout_log_l1") -> dict[str, dict[int, float]]:
    """contender -> size -> the median over materials of ``field``."""
    out: dict[str, dict[int, list[float]]] = {}
    for p in points:
        if p.protocol == protocol:
            out.setdefault(p.contender, {}).setdefault(p.n_fit, []).append(getattr(p, field))
    return {c: {n: statistics.median(v) for n, v in sorted(by_n.items())} for c, by_n in out.items()}


def wins(points: Sequence[CurvePoint], protocol: str, a: str, b: str) -> dict[int, tuple[int, int]]:
    """size -> (materials where ``a`` has the lower held-out error than ``b``, materials measured)."""
    table: dict[tuple[str, int], dict[str, float]] = {}
    for p in points:
        if p.protocol == protocol and p.contender in (a, b):
            table.setdefault((p.material, p.n_fit), {})[p.contender] = p.heldout_log_l1
    out: dict[int, list[int]] = {}
    for (_, n), losses in table.items():
        if a in losses and b in losses:
            counts = out.setdefault(n, [0, 0])
            counts[0] += losses[a] < losses[b]
            counts[1] += 1
    return {n: (c[0], c[1]) for n, c in sorted(out.items())}


def crossover(points: Sequence[CurvePoint], protocol: str, a: str, b: str, at_least: int) -> int | None:
    """The largest size at which ``a`` beats ``b`` on at least ``at_least`` materials (None: at none)."""
    ahead = [n for n, (won, _) in wins(points, protocol, a, b).items() if won >= at_least]
    return max(ahead) if ahead else None

