"""Scenes: model only what a scene needs (issue 15).

* ``spec`` — the scene file: materials with weights, a ladder of models cheapest first, a tolerance,
  the fit and render setup;
* ``ladder`` — the rungs behind one fit interface, and their measured cost;
* ``planner`` — per material, the cheapest rung within tolerance, and the frame totals;
* ``outputs`` — what a plan writes: plan.json, plan.md, its figures and the pruned bundles.

Pure library code: no HTTP, no Ray, no SQL (the service runs plans as a job kind of its own).
"""

from .planner import MaterialPlan, Plan, plan_scene
from .spec import SceneError, SceneSpec, load_scene, parse_scene

__all__ = ["MaterialPlan", "Plan", "SceneError", "SceneSpec", "load_scene", "parse_scene", "plan_scene"]
