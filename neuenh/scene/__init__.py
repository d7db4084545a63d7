"""Scenes: model only what a scene needs (issue 15).

* ``spec`` — the scene file: materials with weights, a ladder of models cheapest first, a tolerance,
  the fit and render setup;
* ``ladder`` — the rungs behind one fit interface, and their measured cost;
* ``planner`` — per material, the cheapest rung within tolerance, and the frame totals;
* ``outputs`` — what a plan writes: plan.json, plan.md, its figures and the pruned bundles.

Pure library code: no HTTP, no Ray, no SQL (the service runs plans as a job kind of its own). Reading
and checking a scene file imports no torch (``neuenh-client plan`` does it before it sends the scene):
the planner's names load on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .spec import SceneError, SceneSpec, load_scene, parse_scene

if TYPE_CHECKING:
    from .planner import MaterialPlan, Plan, plan_scene

__all__ = ["MaterialPlan", "Plan", "SceneError", "SceneSpec", "load_scene", "parse_scene", "plan_scene"]


def __getattr__(name: str):
    """The planner's names (PEP 562), imported when first asked for: they need torch."""
    if name in ("MaterialPlan", "Plan", "plan_scene"):
        from . import planner

        return getattr(planner, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
