"""``neuenh render``: a sphere rendered with a model, with measured ground truth, or both side by side.

    neuenh render --model ggx -o out/                                  # default parameters, studio light
    neuenh render --model models/enhanced-ggx --material 0 -o out/     # a bundle's fitted material
    neuenh render --model ggx --params fit.json -o out/                # `neuenh fit --json` output
    neuenh render --truth ../shared/data/rgl/paper_white_rgb.bsdf --model ggx --params fit.json -o out/
    neuenh render --model ggx --light "1,1,1:3,3,3" --env studio -o out/

The model (``--model NAME|BUNDLE_DIR``) takes its parameters from ``--params FILE`` (the JSON that
``neuenh fit --json`` prints; the first material, or ``--material NAME|INDEX``), else from the
bundle's fitted materials (``--material``, default the first), else the paper's initial values
(the mean of every parameter's range; latent 0.5).

Ground truth is ``--truth FILE`` (an RGL .bsdf, MERL .binary or NBRDF .npz; ``--truth-material``
picks an NBRDF network) or ``--truth-model NAME|BUNDLE_DIR`` with ``--truth-params FILE`` /
``--truth-material`` as for the model. With a truth and a model, both are rendered with the same
light samples (they share their noise) and the error map, SSIM and ΔE_ITP are reported.
Without ``--model``, a truth is rendered alone; with neither, the model is ``ggx``.

Lighting: ``--env studio`` (procedural, neuenh.render.envmaps) or ``--env FILE.exr`` (lat-long), and
``--light "x,y,z:r,g,b"`` directional lights (world direction towards the light, x right, y up,
z towards the camera; irradiance RGB or one value; repeatable). With no ``--light`` the default
environment is the studio; with ``--light`` only, there is no environment unless ``--env`` is given.

Writes into ``-o DIR``: ``model.exr`` / ``model.png``, with a truth ``truth.exr`` / ``truth.png``,
and with both ``error.png`` (relative luminance error); always ``render.json`` with the settings,
timings and metrics. Existing files are not overwritten without ``--force``.

Metrics (neuenh.render.metrics, over the sphere's pixels): SSIM of the tone-mapped images at the
PNGs' ``--exposure``, and mean ΔE_ITP of the linear renders (linear 1.0 = 100 cd/m², exposure not
applied), in ITU-R BT.2124 units (1 ≈ one just-noticeable difference). The paper's "ΔE_ITP × 10³"
values imply a luminance scale it does not state; ours are not multiplied (neuenh.render.metrics).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from neuenh.files import atomic_write
from neuenh.pretrained import bundle_path

from .fit_reports import read_fit_report
from .outputs import output_folder

if TYPE_CHECKING:
    from neuenh.materials import MaterialParams

# torch and the models are imported where they are used: `neuenh render --help` needs neither.

DEFAULT_SAMPLES = 16


def configure(p: argparse.ArgumentParser) -> None:
    """``neuenh render``'s arguments, on the parser ``cli.main`` made for it (with its one-line help)."""
    p.description = __doc__
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--model", help="an analytical model (ggx, ...) or a bundle directory "
                                   "(default: ggx when no truth is given)")
    p.add_argument("--params", type=Path, help="parameters as printed by `neuenh fit --json`")
    p.add_argument("--material", help="which material (name or index) of --params or of the bundle")
    truth = p.add_mutually_exclusive_group()
    truth.add_argument("--truth", type=Path, help="measured ground truth: RGL .bsdf, MERL .binary, NBRDF .npz")
    truth.add_argument("--truth-model", help="an analytical model or bundle directory as ground truth")
    p.add_argument("--truth-params", type=Path, help="parameters of --truth-model (`neuenh fit --json` output)")
    p.add_argument("--truth-material", help="the NBRDF network of --truth, or the material of --truth-model")
    p.add_argument("--env", help="'studio' (procedural) or a lat-long .exr "
                                 "(default: studio unless --light is given)")
    p.add_argument("--light", action="append", default=[], metavar="X,Y,Z:R,G,B",
                   help="a directional light: direction towards it, then irradiance (repeatable)")
    p.add_argument("--samples", type=int, default=DEFAULT_SAMPLES, metavar="N",
                   help=f"environment samples: a stratified N x N set per pixel (default {DEFAULT_SAMPLES})")
    p.add_argument("--seed", type=int, default=0, help="seed of the environment samples (default 0)")
    p.add_argument("--sampling", choices=("mis", "light"), default="mis",
                   help="environment sampling: mis (default; the map, a cosine lobe and GGX reflection lobes "
                        "mixed, right for glossy materials) or light (the map alone)")
    p.add_argument("--size", type=int, default=256, help="image width and height in pixels (default 256)")
    p.add_argument("--scene", choices=("sphere", "ball"), default="sphere",
                   help="the sphere alone, or resting on a grey ground plane with shadows (ball)")
    p.add_argument("--exposure", type=float, default=0.0, help="exposure of the PNGs and SSIM, in stops")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: all)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("-o", "--output", type=Path, required=True, help="output directory")
    p.set_defaults(run=run)


# -- parsing --------------------------------------------------------------------------------------

def parse_light(text: str) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """``"x,y,z:r,g,b"`` (or ``"x,y,z:v"``, or ``"x,y,z"`` for white 1) -> (direction, irradiance)."""
    where, _, power = text.partition(":")
    try:
        direction = [float(v) for v in where.split(",")]
        radiance = [float(v) for v in power.split(",")] if power.strip() else [1.0]
    except ValueError:
        direction, radiance = [], []
    ok = (len(direction) == 3 and len(radiance) in (1, 3)
          and all(math.isfinite(v) for v in direction + radiance) and min(radiance) >= 0
          and any(v != 0 for v in direction))
    if not ok:
        raise ValueError(f"--light {text!r}: expected 'x,y,z:r,g,b' (a non-zero direction towards the "
                         "light, then a non-negative irradiance: three values or one)")
    return tuple(direction), tuple(radiance) * 3 if len(radiance) == 1 else tuple(radiance)


def _lighting(args) -> dict:
    """The lighting settings, checked (no file is read yet)."""
    if args.samples < 1:
        raise ValueError(f"--samples must be at least 1, got {args.samples}")
    directional = [parse_light(text) for text in args.light]
    env = args.env if args.env is not None else (None if directional else "studio")
    if env not in (None, "studio") and not Path(env).is_file():
        what = "not a regular file" if Path(env).exists() else "no such file"
        raise FileNotFoundError(f"--env {env}: {what} (give 'studio' or a lat-long .exr)")
    return {"environment": env, "samples": (args.samples ** 2) if env else 0, "samples_per_axis": args.samples,
            "seed": args.seed, "sampling": args.sampling, "directional": [{"direction": list(d), "irradiance": list(e)} for d, e in directional]}


def _lights(info: dict) -> list:
    from neuenh.render import DirectionalLight, EnvironmentMap
    from neuenh.render.envmaps import studio_environment

    env, n, seed = info["environment"], info["samples_per_axis"], info["seed"]
    lights: list = []
    if env == "studio":
        lights.append(EnvironmentMap(studio_environment(), samples_per_axis=n, seed=seed))
    elif env is not None:
        lights.append(EnvironmentMap.from_exr(env, samples_per_axis=n, seed=seed))
    lights.extend(DirectionalLight(tuple(d["direction"]), tuple(d["irradiance"])) for d in info["directional"])
    return lights


def _regular_file(path: Path, what: str) -> None:
    """A missing path and one that is not a regular file (a folder, a FIFO) are different mistakes."""
    if not path.exists():
        raise FileNotFoundError(f"{what}: no such file")
    if not path.is_file():
        raise ValueError(f"{what}: not a regular file")


def _pick(names: list[str], material: str | None, where: str) -> int:
    if material is None:
        return 0
    if material in names:
        return names.index(material)
    if material.lstrip("-").isdigit():
        index = int(material)
        if 0 <= index < len(names):
            return index
        raise ValueError(f"material index {index} out of range: {where} has {len(names)} material(s)")
    raise ValueError(f"no material {material!r} in {where}; it has {names}")


def _initial_params(model) -> MaterialParams:
    import torch

    from neuenh.materials import LATENT_INIT, MaterialParams

    latent = torch.full((model.latent_dim,), LATENT_INIT, dtype=torch.float32) if model.uses_latent else None
    return MaterialParams(model.specs.init_values(), latent)


def _model_source(spec: str, params_file: Path | None, material: str | None, flag: str):
    """(description, brdf) of a model with its parameters; ``flag`` names the material flag
    (``--material`` or ``--truth-material``), the model's and the parameters' flags follow from it."""
    import torch

    from neuenh.checkpoint import Bundle
    from neuenh.fit import model_for
    from neuenh.pretrained import load_model
    from neuenh.render import model_brdf

    truth = flag.startswith("--truth")
    path = bundle_path(spec)
    bundle = Bundle.load(path) if path is not None else None
    model = bundle.model if bundle is not None else load_model(spec, "--truth-model" if truth else "--model")[0]
    if params_file is not None:
        fitted = read_fit_report(params_file, model, "--truth-params" if truth else "--params")
        names = list(fitted)
        name = names[_pick(names, material, str(params_file))]
        params, origin = fitted[name], str(params_file)
    elif bundle is not None and bundle.materials is not None:
        names = list(bundle.materials.names)
        index = _pick(names, material, f"the bundle {spec}")
        name, params, origin = names[index], bundle.materials.as_params(index), f"bundle {spec}"
    else:
        if material is not None:
            raise ValueError(f"{flag} {material!r} needs parameters to choose from: a --params file "
                             "or a bundle with fitted materials")
        name, params, origin = "initial", _initial_params(model), "initial values (mean of the ranges)"
    own = model_for(model, params)  # a material fitted at an analytical capacity: that capacity's model
    if own.uses_latent and params.latent is None:
        raise ValueError(f"{origin}: material {name!r} has no latent code, which model {model.name} needs")
    brdf = model_brdf(own, params)  # (own is its own capacity's model: not built a second time)
    # evaluate once so that wrong names, widths or ranges fail before any rendering
    probe = torch.tensor([[0.0, 0.0, 1.0]])
    brdf(probe, probe)
    return {"model": model.name, "state": model.state, "spec": spec, "material": name,
            "params_from": origin, **own.used_params(params).to_json(digits=6)}, brdf


def _truth_source(args):
    if args.truth is not None:
        from neuenh.data.measured import load_measured

        material = load_measured(args.truth, args.truth_material)
        if not hasattr(material, "evaluate"):
            raise ValueError(f"{args.truth}: a measurement table has no continuous evaluation; "
                             "render ground truth from an RGL, MERL or NBRDF file")
        return {"measured": str(args.truth), "material": material.name}, material.evaluate
    if args.truth_model is not None:
        return _model_source(args.truth_model, args.truth_params, args.truth_material, "--truth-material")
    if args.truth_params is not None:
        raise ValueError("--truth-params needs --truth-model")
    if args.truth_material is not None:
        raise ValueError("--truth-material needs --truth or --truth-model")
    return None, None


# -- the command ----------------------------------------------------------------------------------

def run(args) -> int:
    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    if not 16 <= args.size <= 8192:
        raise ValueError(f"--size must be between 16 and 8192 pixels, got {args.size}")
    if not math.isfinite(args.exposure):
        raise ValueError(f"--exposure must be finite, got {args.exposure}")
    has_truth = args.truth is not None or args.truth_model is not None
    model_spec = args.model if args.model is not None else (None if has_truth else "ggx")
    if model_spec is None and (args.params is not None or args.material is not None):
        raise ValueError("--params and --material need --model")

    # everything that can be wrong is checked before the first (slow) render
    out = output_folder(args.output)
    names = (["model.exr", "model.png"] if model_spec else []) + (["truth.exr", "truth.png"] if has_truth else [])
    if model_spec and has_truth:
        names.append("error.png")
    names.append("render.json")
    existing = [n for n in names if (out / n).exists()]
    if existing and not args.force:
        raise ValueError(f"{out}: {', '.join(existing)} already exist(s); use --force to overwrite")
    light_info = _lighting(args)
    if args.truth is not None:  # the fit reports are checked as they are read (cli.fit_reports), before rendering too
        _regular_file(args.truth, f"--truth {args.truth}")

    from neuenh.render import ball_scene, render, sphere_scene, write_error_map, write_exr, write_png
    from neuenh.render.metrics import delta_e_itp, ssim

    lights = _lights(light_info)
    truth_info, truth_brdf = _truth_source(args)
    model_info, model_brdf = _model_source(model_spec, args.params, args.material, "--material") \
        if model_spec else (None, None)

    scene = ball_scene(args.size) if args.scene == "ball" else sphere_scene(args.size)
    out.mkdir(parents=True, exist_ok=True)
    report: dict = {"size": args.size, "scene": args.scene, "exposure": args.exposure, "lighting": light_info}
    images = {}
    for key, info, brdf in (("truth", truth_info, truth_brdf), ("model", model_info, model_brdf)):
        if brdf is None:
            continue
        start = time.perf_counter()
        image = render(brdf, scene, lights, sampling=light_info["sampling"])
        seconds = time.perf_counter() - start
        if not torch.isfinite(image).all():
            raise ValueError(f"the {key} render has non-finite pixels ({info})")
        write_exr(out / f"{key}.exr", image)
        write_png(out / f"{key}.png", image, exposure=args.exposure)
        images[key] = image
        report[key] = {**info, "render_s": round(seconds, 3)}
    if len(images) == 2:
        mask = scene.mask
        truth, model = images["truth"], images["model"]
        write_error_map(out / "error.png", truth, model, mask=mask, title="relative luminance error, model vs truth")
        report["metrics"] = {"ssim": ssim(truth, model, mask=mask, exposure=args.exposure),
                             "delta_e_itp": delta_e_itp(truth, model, mask=mask)}
    report["files"] = [str(out / n) for n in names]
    _write_json(out / "render.json", report)
    print(json.dumps(report, indent=2) if args.json else _summary(report))
    return 0


def _write_json(path: Path, doc: dict) -> None:
    atomic_write(path, json.dumps(doc, indent=2) + "\n")


def _summary(report: dict) -> str:
    light = report["lighting"]
    parts = []
    if light["environment"]:
        parts.append(f"env {light['environment']} ({light['samples']} samples, {light['sampling']} sampling)")
    if light["directional"]:
        parts.append(f"{len(light['directional'])} directional light(s)")
    lines = [f"{report['size']}x{report['size']} sphere, " + ", ".join(parts)]
    for key in ("truth", "model"):
        if key in report:
            r = report[key]
            what = r.get("measured") or f"{r['model']} (state {r['state']}), {r['params_from']}"
            lines.append(f"  {key}: {what}, material {r['material']!r}, {r['render_s']:.2f} s")
    if "metrics" in report:
        m = report["metrics"]
        lines.append(f"  SSIM {m['ssim']:.4f}  ΔE_ITP {m['delta_e_itp']:.3f}")
    lines.append("wrote " + ", ".join(report["files"]))
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    sys.exit("run as `neuenh render` (python -m neuenh_service.cli.main render)")
