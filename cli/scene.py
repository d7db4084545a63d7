"""``neuenh scene plan``: model only what a scene needs.

    neuenh scene plan scene.yaml -o DIR [--json]

For every material of the scene (``neuenh.scene.spec``: measured files, tables or an EXR capture's
texels, each with a weight), fit every rung of its ladder, measure each rung's error on held-out
samples (or in renders) and its cost on this machine, and choose the cheapest rung within the
scene's tolerance. Writes DIR/plan.json, DIR/plan.md, DIR/cost_vs_error.png, DIR/contact_sheet.png
and DIR/bundles/ (only the rungs the plan uses). Each material's result is kept in DIR/materials/ as
it is planned: running the same command again after an interruption plans only the rest.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from neuenh.files import atomic_write, is_temporary

from .outputs import output_folder
from .progress import StepBar
from .tables import help_description, plan_totals

if TYPE_CHECKING:  # neuenh.scene imports torch (~1.5 s): `neuenh scene --help` need not pay it
    from neuenh.scene import MaterialPlan


def configure(p: argparse.ArgumentParser) -> None:
    """``neuenh scene``'s arguments, on the parser ``cli.main`` made for it (with its one-line help)."""
    description = help_description(__doc__)
    p.description = description
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    plan = actions.add_parser("plan", help="choose each material's rung and write the plan", description=description)
    plan.add_argument("scene", type=Path, metavar="SCENE.yaml", help="the scene (e.g. examples/scene.yaml)")
    plan.add_argument("-o", "--output", required=True, type=Path, metavar="DIR",
                      help="folder of the plan's files (kept between runs: an interrupted plan resumes)")
    plan.add_argument("--json", action="store_true", help="print the plan's totals as JSON")
    plan.add_argument("--no-sheet", action="store_true", help="skip the contact sheet (its renders)")
    plan.add_argument("--chunk", type=int, default=8, metavar="N",
                      help="materials fitted together (each chunk is kept as it finishes; default 8)")
    plan.set_defaults(run=run)


def run(args) -> int:
    from neuenh.scene import load_scene, plan_scene
    from neuenh.scene.outputs import write_plan

    output_folder(args.output)
    spec, base = load_scene(args.scene)
    progress = StepBar(sys.stderr)
    kept = args.output / "materials"
    done = _read_done(kept)
    if done:
        progress.note(f"resuming: {len(done)} material(s) already planned in {kept}")

    def keep(plan: MaterialPlan) -> None:
        kept.mkdir(parents=True, exist_ok=True)
        atomic_write(kept / _file(plan.name), json.dumps(plan.to_json()))

    if args.chunk < 1:
        raise ValueError(f"--chunk must be at least 1, got {args.chunk}")
    plan = plan_scene(spec, base, done=done, on_material=keep, progress=progress, chunk=args.chunk)
    progress.done()
    write_plan(plan, args.output, sheet=not args.no_sheet)
    totals = plan.totals()
    if args.json:
        print(json.dumps({"plan": str(args.output / "plan.json"), "totals": totals}, indent=1))
    else:
        for m in plan.materials:
            print(f"{m.name:32s} {plan.rung_info(m.chosen)['label']:40.40s} error {m.result(m.chosen).error:.4f}")
        print(plan_totals(totals))
        print(f"wrote {args.output / 'plan.md'}")
    return 0


def _file(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name) + ".json"


def _read_done(folder: Path) -> dict[str, MaterialPlan]:
    """Materials an interrupted run planned; an unreadable file is planned again, and the temporary
    file of a write the interruption cut short is not read."""
    from neuenh.scene import MaterialPlan

    out = {}
    for path in sorted(p for p in folder.glob("*.json") if not is_temporary(p)):  # none when the folder is absent
        try:
            plan = MaterialPlan.from_json(json.loads(path.read_text()))
        except (ValueError, KeyError, TypeError):
            continue
        out[plan.name] = plan
    return out


