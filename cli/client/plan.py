"""``neuenh-client plan SCENE.yaml [--upload] [--wait] [-o DIR]``: plan a scene on the service (what
``neuenh scene plan`` does locally): per material the cheapest rung within the scene's tolerance.
The scene is checked here first, so a bad one is a usage error before the service is contacted.
Relative paths that name files beside the scene are sent absolute (a service on this machine reads
them where they are); ``--upload`` sends the measured files themselves."""

from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path

from neuenh.files import atomic_write

from ..outputs import output_folder
from ..tables import plan_totals, table
from .api import DOWNLOAD_TIMEOUT_S, Api
from .commands import Commands, json_arg, note, print_json


def add_parser(commands: Commands) -> None:
    p = commands.add("plan", run, "plan a scene on the service: per material the cheapest model within tolerance")
    p.add_argument("scene", type=Path, metavar="SCENE.yaml",
                   help="a scene (neuenh scene plan's format); its files are read by the service, under its data "
                        "roots, unless --upload sends them")
    p.add_argument("--upload", action="store_true",
                   help="send the scene's measured files (tables, RGL .bsdf, MERL .binary) with it, for a service "
                        "that cannot read them where they are")
    p.add_argument("--wait", action="store_true", help="follow the plan until it ends; exit 1 if it failed")
    p.add_argument("-o", "--output", type=Path, metavar="DIR", help="with --wait: save the plan's files here")
    p.add_argument("--idempotency-key", metavar="KEY", help="submitting again with the same key returns the same plan")
    p.add_argument("--interval", type=float, default=1.0, metavar="SECONDS", help="how often to poll (default 1)")
    json_arg(p, "print the plan as JSON")


def run(args, api: Api) -> int:
    from neuenh.scene import load_scene

    if args.output is not None:  # where the files go is checked before the plan is submitted, not after it ran
        if not args.wait:
            raise ValueError("-o saves the plan's files once it is done: it needs --wait")
        output_folder(args.output)
    spec, base = load_scene(args.scene)  # a bad scene is a usage error before the service is contacted
    scene = _service_paths(spec.model_dump(mode="json", exclude_none=True), base)
    if args.upload:
        scene, paths = _uploaded(scene)
        with contextlib.ExitStack() as stack:
            files = [(p.name, stack.enter_context(open(p, "rb"))) for p in paths]
            found, created = api.submit_plan_with_files(scene, files, args.idempotency_key,
                                                        read_timeout=args.timeout or DOWNLOAD_TIMEOUT_S)
    else:
        found, created = api.submit_plan(scene, args.idempotency_key)
    note(f"plan {found['id']} {'submitted' if created else 'already submitted with this key'} "
         f"({found['status'].lower()})")
    if not args.wait:
        print(json.dumps(found, indent=2) if args.json else found["id"])
        return 0
    last = None
    while not found["terminal"]:
        progress = found.get("progress")
        line = (f"plan {found['id']}: {found['materials_done']}/{found['materials_total'] or '?'} materials"
                + (f", {progress['step']}/{progress['steps']} fits ({progress['message']})" if progress else ""))
        if line != last:
            note(line)
            last = line
        time.sleep(max(args.interval, 0.05))
        found = api.plan(found["id"])
    if args.output and found["status"] == "DONE":
        args.output.mkdir(parents=True, exist_ok=True)
        for name in found["files"]:
            atomic_write(args.output / name, api.plan_file(found["id"], name))
    if args.json:
        print_json(found)
    elif found["status"] == "DONE":
        result = found["plan"]
        labels = {r["key"]: r["label"] for r in result["ladder"]}
        print(table([("material", "chosen rung", "error", "cost (ns)")]
                    + [(m["name"], labels[m["chosen"]][:40], f"{m['error']:.4f}", f"{m['cost_ns']:.0f}")
                       for m in result["materials"]], right=(2, 3)))
        print(plan_totals(result["totals"]))
        if args.output:
            note(f"saved {', '.join(found['files'])} to {args.output}")
    else:
        note(f"plan {found['id']}: FAILED: {found['error']}")
    return 0 if found["status"] == "DONE" else 1


def _service_paths(scene: dict, base: Path) -> dict:
    """A scene's relative paths that name files beside it here, made absolute: the service resolves
    relative paths against its own working directory (a service on this machine then reads the same
    files; for one elsewhere, write the paths it sees)."""
    def fix(path: str) -> str:
        here = base / path
        return str(here.resolve()) if not Path(path).is_absolute() and here.exists() else path

    for m in scene["materials"]:
        for key in ("path", "capture"):
            if key in m:
                m[key] = fix(m[key])
    def fix_model(name: object) -> object:  # a bundle folder's path, not a model's name
        return fix(name) if isinstance(name, str) and ("/" in name or (base / name).is_dir()) else name

    scene["ladder"] = [{k: fix_model(v) if k in ("rungs", "model") else v for k, v in r.items()}
                       if isinstance(r, dict) else fix_model(r) for r in scene["ladder"]]
    return scene


def _uploaded(scene: dict) -> tuple[dict, list[Path]]:
    """The scene with each measured file named by its file name alone, and the files to send; a
    capture (a folder of texels) is not sent: one line says so."""
    paths: list[Path] = []
    for i, m in enumerate(scene["materials"]):
        if "capture" in m:
            raise ValueError(f"materials.{i}: a capture ({m['capture']}) cannot be uploaded; put it under the "
                             "service's data roots and plan without --upload")
        path = Path(m["path"])
        if not path.is_file():
            raise ValueError(f"materials.{i}: {path}: no such file to upload")
        clash = next((p for p in paths if p.name == path.name), None)
        if clash is not None:
            raise ValueError(f"materials.{i}: {path} and {clash} share the file name {path.name!r}; rename one "
                             "to upload both")
        paths.append(path)
        m["path"], m["name"] = path.name, m.get("name") or path.stem
    return scene, paths
