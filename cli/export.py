"""``neuenh export``: fitted materials of a model, in a renderer's own format.

    neuenh export MODEL --format glsl|onnx|mitsuba -o DIR [--params FIT.json] [--material NAME ...]
    neuenh export --plan DIR/plan.json --format glsl|onnx|mitsuba -o OUT [--material NAME ...]
    neuenh export NBRDF.npz --format glsl|onnx|mitsuba -o DIR [--material NAME ...]

``MODEL`` is a bundle folder (e.g. one written by ``neuenh fit -o DIR``, which holds the fitted
materials), a shipped model, an analytical model, or a file of NBRDF networks (the published networks
of the MERL materials, ``../shared/data/merl_nbrdf``: each a material of its own, exported as a plan's
NBRDF materials are, so a measured MERL material renders in the same renderer as a fitted model). The
materials exported are the bundle's own, or
with ``--params`` those of a fit report (``neuenh fit --json``, or the answer of ``POST
/v1/jobs/{id}/fit``), which must be a fit of this very model; ``--material`` picks some by name.
With ``--plan`` (written by ``neuenh scene plan``) every material is exported with the rung the plan
chose for it, one folder per rung (``OUT/<rung>/``), each holding only that rung's modules; the
materials planned with the per-material NBRDF rung are written from their networks into
``OUT/nbrdf/`` (``neuenh.export.nbrdf``: the same files and function names). A material fitted at an
analytical capacity (``neuenh fit --capacity auto`` may choose one) is evaluated by an analytical
model of the same graph, not by the modules: it is written with that model into a folder named after
its capacity inside the model's (``OUT/original/``, ``OUT/<rung>/analytical/``).
Each format's files are described in docs/EXPORT.md and ``neuenh.export``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from neuenh.export import FORMATS, export, export_nbrdf

from .fit_reports import read_fit_report
from .outputs import output_folder
from .tables import help_description

if TYPE_CHECKING:  # the models' modules import torch (~1.5 s): `neuenh export --help` need not pay it
    from neuenh.materials import MaterialParams


def configure(p: argparse.ArgumentParser) -> None:
    """``neuenh export``'s arguments, on the parser ``cli.main`` made for it (with its one-line help)."""
    p.description = help_description(__doc__)
    p.add_argument("model", metavar="MODEL", nargs="?",
                   help="a bundle folder, a shipped model, an analytical model or an NBRDF networks file "
                        "(not with --plan)")
    p.add_argument("--format", required=True, choices=FORMATS, help="what to write")
    p.add_argument("-o", "--output", required=True, type=Path, metavar="DIR", help="folder to write into")
    p.add_argument("--params", type=Path, metavar="FIT.json",
                   help="a fit report of this model (neuenh fit --json); default: the bundle's own materials")
    p.add_argument("--plan", type=Path, metavar="PLAN.json",
                   help="a scene plan (neuenh scene plan): each material with the rung chosen for it")
    p.add_argument("--material", action="append", metavar="NAME", help="only this material (repeat for more)")
    p.set_defaults(run=run)


def run(args) -> int:
    if (args.model is None) == (args.plan is None):
        raise ValueError("give a MODEL or --plan PLAN.json (one of them)")
    if args.plan and args.params:
        raise ValueError("--params goes with a MODEL; a plan holds its materials' parameters")
    output_folder(args.output)
    wanted = set(args.material or ())
    networks: dict = {}  # name -> NBRDFNetwork: a plan's NBRDF materials, or an NBRDF file's networks
    if args.plan:
        from neuenh.scene.ladder import NBRDFRung
        from neuenh.scene.outputs import plan_models, safe_name

        planned = plan_models(args.plan)
        groups = [group for key, model, materials in planned.groups
                  for group in by_own_model(args.output / safe_name(key), model, materials)]
        networks = planned.nbrdf
        networks_folder = args.output / safe_name(NBRDFRung.key)
    elif is_nbrdf_file(args.model):
        if args.params:
            raise ValueError(f"--params goes with a model; {args.model} holds its networks' weights")
        groups, networks, networks_folder = [], published_networks(Path(args.model), wanted), args.output
    else:
        from neuenh.pretrained import load_model

        try:
            model, trained = load_model(args.model, "MODEL")
        except ValueError as exc:
            if Path(args.model).suffix != ".json" or args.params:
                raise
            raise ValueError(f"{exc}; a fit report (neuenh fit --json) goes with the model it fitted: "
                             f"neuenh export MODEL --params {args.model}") from None
        materials = read_fit_report(args.params, model) if args.params else bundle_materials(trained, args.model)
        groups = by_own_model(args.output, model, materials)
    every = {m for _, _, materials in groups for m in materials} | set(networks)
    missing = sorted(wanted - every)
    if missing:
        raise ValueError(f"no material {', '.join(map(repr, missing))}; there are: {', '.join(sorted(every))}")
    for folder, model, materials in groups:
        chosen = {m: p for m, p in materials.items() if not wanted or m in wanted}
        if chosen:
            for path in export(model, chosen, args.format, folder):
                print(path)
    chosen_networks = {m: net for m, net in networks.items() if not wanted or m in wanted}
    if chosen_networks:
        for path in export_nbrdf(chosen_networks, args.format, networks_folder):
            print(path)
    return 0


def is_nbrdf_file(model_arg: str) -> bool:
    """Whether MODEL names a file of NBRDF networks (by its content; a model's name or folder is not)."""
    from neuenh.data.errors import DataError
    from neuenh.data.formats import detect_format

    try:
        return detect_format(model_arg) == "nbrdf"
    except (DataError, OSError):  # no such file, a folder, not data: load_model says what a MODEL may be
        return False


def published_networks(path: Path, wanted: set[str]) -> dict:
    """Name -> ``NBRDFNetwork`` of the file's networks (``wanted`` ones, or all), in the file's order;
    a name it does not hold is a ValueError naming the file (``neuenh.data.nbrdf``)."""
    from neuenh.data.nbrdf import load_nbrdf, nbrdf_material
    from neuenh.study.nbrdf_fit import NBRDFNetwork

    held = load_nbrdf(path)  # the file read once
    for name in sorted(wanted - set(held)):
        nbrdf_material(path, name)  # raises the reader's error: the file and the names it holds
    return {name: NBRDFNetwork.from_published(m.weights) for name, m in held.items() if not wanted or name in wanted}


def by_own_model(folder: Path, model, materials: dict[str, MaterialParams]) -> list[tuple[Path, object, dict]]:
    """``materials`` of ``model`` as (folder, model, materials) groups by the model that evaluates
    each (``neuenh.fit.model_for``): ``model``'s into ``folder``, those fitted at an analytical
    capacity with that capacity's model into ``folder/<capacity>``."""
    from neuenh.fit import model_for

    owns: dict[str | None, object] = {}  # capacity -> the model that evaluates it
    groups: dict[Path, tuple[object, dict]] = {}
    for name, params in materials.items():
        if params.capacity not in owns:  # model_for builds an analytical capacity's model: once each
            owns[params.capacity] = model_for(model, params)
        own = owns[params.capacity]
        where = folder if own is model else folder / params.capacity
        groups.setdefault(where, (own, {}))[1][name] = own.used_params(params)
    return [(where, own, chosen) for where, (own, chosen) in groups.items()]


def bundle_materials(table, model_arg: str) -> dict[str, MaterialParams]:
    if table is None or not len(table):
        raise ValueError(f"{model_arg} holds no materials; fit some first (neuenh fit --model {model_arg} ... -o DIR) "
                         "and export that folder, or pass --params FIT.json")
    return {name: table.as_params(i) for i, name in enumerate(table.names)}
