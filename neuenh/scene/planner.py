"""The scene planner: per material, the cheapest rung of the ladder within tolerance ("model only
what a scene needs").

For every material of the scene (``spec.SceneSpec``) it draws a fit set and a test set
(``study.heldout.draw_fit_test``, a share of the pairs near the mirror direction), fits every rung of
the ladder (``ladder.Rung``, several materials in one batch), measures each fitted rung's error — the
held-out log-L1, and with a render metric ΔE_ITP or 1 − SSIM of a render against the measured truth
under the same light samples (``study.comparison.RenderSetup``) — and its cost, nanoseconds per
evaluation of its specialized BRDF on this machine, measured for all rungs side by side once the
first chunk's fits are done (``ladder.rung_costs``), beside its bytes of per-material parameters. The
material gets the cheapest rung within tolerance (``spec.Tolerance``); a rung listed later in the
ladder is preferred to an earlier one only when it is more than ``COST_MARGIN`` cheaper, so timing
noise between rungs of nearly equal cost cannot change a plan.

Materials are planned in chunks; ``on_material`` receives each finished ``MaterialPlan`` (a caller
persists it) and ``done`` gives back those of an interrupted run, which are not planned again. The
frame totals weigh each material by its ``weight``: the weighted mean cost and error of the plan,
of the richest rung everywhere and of the cheapest rung everywhere.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import torch

from ..data.samples import Samples
from ..fit import FitOptions
from ..study.comparison import RenderSetup
from ..study.heldout import draw_fit_test
from .ladder import FittedRung, Rung, build_ladder, rung_brdf, rung_costs
from .spec import CaptureEntry, FileEntry, SceneError, SceneSpec

__all__ = ["COST_MARGIN", "MaterialPlan", "Plan", "RungResult", "SceneMaterial", "load_materials", "plan_scene"]

COST_MARGIN = 0.10  # a later rung must be this much cheaper to be preferred to an earlier one
CHUNK = 8  # materials fitted together


@dataclass
class RungResult:
    """One rung fitted to one material."""

    rung: str  # Rung.key
    error: float  # the tolerance's metric (1 - SSIM for ssim)
    heldout_log_l1: float
    fit_loss: float
    n_params: int
    param_bytes: int
    params: dict[str, list[float]] = field(repr=False)
    delta_e_itp: float | None = None
    ssim: float | None = None


@dataclass
class MaterialPlan:
    name: str
    weight: float
    chosen: str  # the key of the chosen rung
    results: list[RungResult]  # in ladder order

    def result(self, key: str) -> RungResult:
        return next(r for r in self.results if r.rung == key)

    def to_json(self) -> dict:
        return {"name": self.name, "weight": self.weight, "chosen": self.chosen,
                "results": [asdict(r) for r in self.results]}

    @classmethod
    def from_json(cls, data: Mapping) -> "MaterialPlan":
        return cls(data["name"], float(data["weight"]), data["chosen"], [RungResult(**r) for r in data["results"]])


@dataclass
class SceneMaterial:
    name: str
    material: Any  # a measured material (continuous: has ``evaluate``; a table: has ``table``)
    weight: float

    @property
    def renderable(self) -> bool:
        return callable(getattr(self.material, "evaluate", None))


@dataclass
class Plan:
    scene: SceneSpec
    ladder: list[dict]  # per rung: key, label, model, state, shared weights, cost_ns, source, round
    materials: list[MaterialPlan]
    rungs: list[Rung] = field(default_factory=list, repr=False)  # the ladder's rungs, ladder order
    sources: list[SceneMaterial] = field(default_factory=list, repr=False)  # the measured materials

    def rung(self, key: str) -> Rung:
        return next(r for r in self.rungs if r.key == key)

    def rung_info(self, key: str) -> dict:
        return next(r for r in self.ladder if r["key"] == key)

    def totals(self) -> dict[str, dict]:
        """Weighted frame cost (ns per evaluation) and error, and bytes of per-material parameters, of
        the plan, of the richest rung everywhere and of the cheapest rung everywhere."""
        weights = [m.weight for m in self.materials]
        total = sum(weights) or 1.0

        def frame(pick: Callable[[MaterialPlan], str]) -> dict:
            keys = [pick(m) for m in self.materials]
            results = [m.result(k) for m, k in zip(self.materials, keys)]
            return {
                "cost_ns": sum(w * self.rung_info(k)["cost_ns"] for w, k in zip(weights, keys)) / total,
                "error": sum(w * r.error for w, r in zip(weights, results)) / total,
                "heldout_log_l1": sum(w * r.heldout_log_l1 for w, r in zip(weights, results)) / total,
                "param_bytes": sum(r.param_bytes for r in results),
                "rungs": {k: keys.count(k) for k in dict.fromkeys(keys)},
            }

        richest, cheapest = self.ladder[-1]["key"], self.ladder[0]["key"]
        return {"plan": frame(lambda m: m.chosen), "richest": frame(lambda m: richest),
                "cheapest": frame(lambda m: cheapest)}

    def to_json(self) -> dict:
        richest = self.ladder[-1]["key"]
        return {
            "scene": self.scene.model_dump(mode="json"),
            "ladder": self.ladder,
            "materials": [{**m.to_json(), "model": self.rung_info(m.chosen)["model"],
                           "state": self.rung_info(m.chosen)["state"],
                           "error": m.result(m.chosen).error, "cost_ns": self.rung_info(m.chosen)["cost_ns"],
                           "params": m.result(m.chosen).params,
                           "richest": {"rung": richest, "error": m.result(richest).error,
                                       "cost_ns": self.rung_info(richest)["cost_ns"]}}
                          for m in self.materials],
            "totals": self.totals(),
        }


# -- materials --------------------------------------------------------------------------------------
def _check_digest(path: Path, sha256: str) -> None:
    """``path``'s content has this SHA-256, or a ValueError says the file was damaged or replaced."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    if digest.hexdigest() != sha256:
        raise ValueError(f"{path}: its content does not match its sha256 {sha256[:12]}... (damaged or replaced); "
                         "not used")


def load_materials(spec: SceneSpec, base: Path) -> list[SceneMaterial]:
    """The scene's materials, their weights shared out (a capture's among its texels); a missing or
    unreadable file, a duplicate name, or a render metric on a material that cannot be rendered is a
    SceneError naming the entry."""
    from ..data.capture import read_capture
    from ..data.errors import DataError
    from ..data.measured import load_measured

    out: list[SceneMaterial] = []
    for i, entry in enumerate(spec.materials):
        try:
            if isinstance(entry, FileEntry):
                if entry.sha256 is not None:
                    _check_digest(base / entry.path, entry.sha256)
                material = load_measured(base / entry.path, entry.name)
                out.append(SceneMaterial(entry.name or material.name, material, entry.weight))
            elif isinstance(entry, CaptureEntry):
                texels = read_capture(base / entry.capture, entry.region, entry.stride).materials()
                out.extend(SceneMaterial(t.name, t, entry.weight / len(texels)) for t in texels)
        except (DataError, OSError, ValueError) as exc:
            raise SceneError(f"materials.{i}: {exc}") from None
    names = [m.name for m in out]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise SceneError(f"materials: {', '.join(twice)} more than once; give each its own 'name'")
    if spec.tolerance.renders:
        flat = [m.name for m in out if not m.renderable]
        if flat:
            raise SceneError(f"tolerance.metric {spec.tolerance.metric} renders each material's truth, but "
                             f"{', '.join(flat[:3])}{' ...' if len(flat) > 3 else ''} can only be measured "
                             "where sampled (a table or texel); use metric log_l1")
    if not sum(m.weight for m in out) > 0:
        raise SceneError("materials: every weight is 0")
    return out


# -- the plan -------------------------------------------------------------------------------------
def choose(results: Sequence[RungResult], costs: Mapping[str, float], tolerance) -> str:
    """The cheapest rung within tolerance (module doc), given each rung's cost in ladder order."""
    best = min(r.error for r in results)
    within = [r.rung for r in results if tolerance.within(r.error, best)]
    if not within:  # an absolute tolerance no rung meets: the best one
        return min(results, key=lambda r: (r.error, costs[r.rung])).rung
    cheapest = min(within, key=lambda k: costs[k])
    return next(k for k in within if costs[k] <= costs[cheapest] * (1.0 + COST_MARGIN))


def plan_scene(spec: SceneSpec, base: Path, *, done: Mapping[str, MaterialPlan] | None = None,
               on_material: Callable[[MaterialPlan], None] | None = None,
               progress: Callable[[str, int, int], None] | None = None,
               ladder: Sequence[Rung] | None = None, chunk: int = CHUNK) -> Plan:
    """Plan every material of ``spec`` (module doc). ``progress(what, done, total)`` is called as
    each (chunk, rung) fit finishes."""
    materials = load_materials(spec, base)
    try:
        rungs = list(ladder) if ladder is not None else build_ladder(spec.ladder)
    except ValueError as exc:
        raise SceneError(str(exc)) from None
    done = dict(done or {})
    stale = [n for n, p in done.items() if [r.rung for r in p.results] != [r.key for r in rungs]]
    for name in stale:  # planned with another ladder: plan again
        done.pop(name)
    todo = [m for m in materials if m.name not in done]
    setup = RenderSetup(spec.render.size, spec.render.samples_per_axis, spec.render.seed, spec.render.scene)
    options = spec.fit.options()
    costs: dict[str, float] = {}
    steps, step = math.ceil(len(todo) / chunk) * len(rungs), 0
    for lo in range(0, len(todo), chunk):
        group = todo[lo : lo + chunk]
        sets = [_draw(m, spec) for m in group]
        fit = Samples.concat([s[0] for s in sets])
        truths = [_truth(m, setup) for m in group] if spec.tolerance.renders else [None] * len(group)
        results: list[list[RungResult]] = [[] for _ in group]
        brdfs = {}  # what the costs are measured on: the first chunk's only
        for rung in rungs:
            fitted = rung.fit(fit, options, seed=spec.fit.seed)
            if not costs:
                brdfs[rung.key] = rung_brdf(fitted)
            for i, (f, (_, test), truth) in enumerate(zip(fitted, sets, truths)):
                results[i].append(_measure(rung.key, f, test, truth, setup, spec.tolerance.metric))
            step += 1
            if progress:
                progress(f"{rung.label} on {len(group)} material(s)", step, steps)
        if not costs:
            costs = rung_costs(brdfs)
        for m, rs in zip(group, results):
            plan = MaterialPlan(m.name, m.weight, choose(rs, costs, spec.tolerance), rs)
            done[m.name] = plan
            if on_material:
                on_material(plan)
    if not costs:  # everything came from ``done``: measure the costs on the first material again
        costs = _remeasure(rungs, materials[0], spec, options)
    info = [{"key": r.key, "label": r.label, "model": r.model_name, "state": r.state,
             "alternatives": bool(getattr(getattr(r, "model", None), "has_alternatives", False)),
             "capacity": getattr(r, "capacity", None), "shared_weights": r.shared_weights, "cost_ns": costs[r.key],
             "source": getattr(r, "source", None), "round": getattr(r, "round", None)} for r in rungs]
    return Plan(spec, info, [done[m.name] for m in materials], list(rungs), materials)


def _draw(m: SceneMaterial, spec: SceneSpec) -> tuple[Samples, Samples]:
    n_test = spec.fit.test_samples
    table = getattr(m.material, "table", None)
    if table is not None:  # disjoint rows: what the table holds beyond the fit set, at most n_test
        if len(table) < 2:
            raise SceneError(f"{m.name}: {len(table)} measurement(s); at least 2 are needed to fit and test")
        n_fit = min(spec.fit.samples, len(table) - 1)
        n_test = min(n_test, len(table) - n_fit)
        fit, test, _ = draw_fit_test(m.material, n_fit, n_test, spec.fit.seed)
    else:
        fit, test, _ = draw_fit_test(m.material, spec.fit.samples, n_test, spec.fit.seed,
                                     near_mirror=spec.fit.near_mirror)
    return _renamed(fit, m.name), _renamed(test, m.name)


def _renamed(samples: Samples, name: str) -> Samples:
    return Samples(samples.wi, samples.wo, samples.f_r, samples.material, (name,))


def _truth(m: SceneMaterial, setup):
    from ..render import render

    scene, lights = setup.build_scene(), setup.lights()
    image = render(lambda wi, wo: m.material.evaluate(wi, wo).float(), scene, lights)
    return image, scene, lights


def _measure(key: str, fitted: FittedRung, test: Samples, truth, setup, metric: str) -> RungResult:
    heldout = fitted.heldout_log_l1(test)
    result = RungResult(key, heldout, heldout, fitted.fit_loss, fitted.n_params, fitted.param_bytes, fitted.params)
    if truth is not None:
        from ..render import render
        from ..render.metrics import delta_e_itp, ssim

        image0, scene, lights = truth
        image = render(fitted.brdf, scene, lights)
        if not torch.isfinite(image).all():
            raise ValueError(f"{key} on {test.names[0]}: the render has non-finite pixels")
        result.delta_e_itp = delta_e_itp(image0, image, mask=scene.mask)
        result.ssim = ssim(image0, image, mask=scene.mask)
        result.error = result.delta_e_itp if metric == "delta_e_itp" else 1.0 - result.ssim
    return result


def _remeasure(rungs, material: SceneMaterial, spec: SceneSpec, options: FitOptions) -> dict[str, float]:
    fit, _ = _draw(material, spec)
    return rung_costs({r.key: rung_brdf(r.fit(fit, options, seed=spec.fit.seed)) for r in rungs})
