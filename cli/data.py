"""``neuenh data``: look at measured data, materialise datasets, picture BRDF slices.

    neuenh data inspect FILE [--json]            what FILE is (by content), its materials, ranges
    neuenh data sample SPEC.yaml -o out.npz      materialise a dataset spec (train/val arrays)
    neuenh data slice FILE -o slice.png [--model ggx|BUNDLE_DIR [--params FIT.json]] [--material NAME]

``inspect`` reads RGL ``.bsdf``, MERL ``.binary``, NBRDF weights, measurement tables (npz or
CSV), capture folders (or their JSON) and parameter EXRs. For continuous materials the value
ranges come from ``--probe`` Rusinkiewicz-uniform samples; for tables from every row.

``sample`` takes a YAML with a ``data:`` list of sources exactly as in a job spec, and optional
``val_fraction`` (default 0.1) and ``seed`` (default 0) — or a whole job spec, whose
``train.val_fraction`` and ``train.seed`` are then used. The ``.npz`` holds ``train_wi``,
``train_wo``, ``train_f_r`` (float32, (n, 3)), ``train_material`` (int64), the same with ``val_``,
``names`` and ``recipe`` (the sources and split as JSON).

``slice`` draws log10 of the luminance of f_r over a 2-D slice: by default (``--view
rusinkiewicz``) over (theta_h, theta_d) at fixed ``--phi-d`` (90 degrees) and phi_h = 0; with
``--view hemisphere``, over every outgoing direction (orthographic view of the hemisphere from
above, +x to the right) for a light at ``--theta-i``. With ``--model`` the model is first fitted
to ``--fit-samples`` samples of the material (``neuenh.fit``, fast protocol) and drawn next to it
with the same colour scale, with a third panel of log10(model / measured); with ``--params`` the fit
a report holds is drawn instead (``neuenh fit --json``: its capacity and corrections as fitted).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from neuenh.data.table import savez
from neuenh.files import atomic_write

from .fit_reports import read_fit_report
from .tables import help_description

if TYPE_CHECKING:  # torch is imported where a command runs: `neuenh data --help` answers without it
    import torch


class DataCommandError(ValueError):
    """A user's mistake in a ``neuenh data`` command (one line, exit code 2)."""


def configure(p: argparse.ArgumentParser) -> None:
    """``neuenh data``'s arguments, on the parser ``cli.main`` made for it (with its one-line help)."""
    p.description = __doc__
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    sub = p.add_subparsers(dest="data_command", required=True, metavar="ACTION")
    # each action's own --help: its paragraph of the module doc (the one that opens with its name)
    about = {par.split("``")[1]: par for par in help_description(__doc__).split("\n\n")}

    i = sub.add_parser("inspect", help="what a data file is, its materials and value ranges",
                       description=about["inspect"])
    i.add_argument("file", type=Path, metavar="FILE", help="the file (or capture folder) to look at")
    i.add_argument("--probe", type=int, default=None,
                   help="samples per continuous material for the value ranges (default 20000, or 2000 each "
                        "for a file of many networks)")
    i.add_argument("--json", action="store_true", help="print the result as JSON")
    i.set_defaults(run=run_inspect)

    s = sub.add_parser("sample", help="materialise a dataset spec into train/val arrays (.npz)",
                       description=about["sample"])
    s.add_argument("spec", type=Path, metavar="SPEC.yaml", help="a data: list of sources, or a whole job spec")
    s.add_argument("-o", "--output", type=Path, required=True, metavar="OUT.npz", help="the arrays' file")
    s.add_argument("--json", action="store_true", help="print the result as JSON")
    s.set_defaults(run=run_sample)

    c = sub.add_parser("slice", help="picture a BRDF slice (PNG), optionally next to a fitted model",
                       description=about["slice"])
    c.add_argument("file", type=Path, metavar="FILE", help="a measured file: RGL, MERL, NBRDF weights or a table")
    c.add_argument("-o", "--output", type=Path, required=True, metavar="SLICE.png", help="the picture")
    c.add_argument("--material", help="which network of an NBRDF file (required when it holds several)")
    c.add_argument("--model", help="fit this model (a name such as ggx, or a bundle directory) and show it too")
    c.add_argument("--params", type=Path, metavar="FIT.json",
                   help="show --model's fit from this report (neuenh fit --json) instead of fitting again: its "
                        "material of FILE's name")
    c.add_argument("--view", choices=("rusinkiewicz", "hemisphere"), default="rusinkiewicz")
    c.add_argument("--phi-d", type=float, default=90.0, help="phi_d of the rusinkiewicz view, degrees (90)")
    c.add_argument("--theta-i", type=float, default=30.0, help="light elevation of the hemisphere view, degrees (30)")
    c.add_argument("--resolution", type=int, default=128, help="pixels per side (128)")
    c.add_argument("--fit-samples", type=int, default=20_000, help="samples the model is fitted to (20000)")
    c.add_argument("--epochs", type=int, default=None, help="fit epochs (default: the fast protocol's 300)")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--json", action="store_true", help="print the result as JSON")
    c.set_defaults(run=run_slice)


# -- inspect ---------------------------------------------------------------------------------
def _ranges(f: torch.Tensor) -> dict:
    f = f.double()
    return {"min": [round(float(v), 6) for v in f.min(0).values], "max": [round(float(v), 6) for v in f.max(0).values],
            "mean": [round(float(v), 6) for v in f.mean(0)]}


def _angles(wi: torch.Tensor, wo: torch.Tensor) -> dict:
    ti = wi[:, 2].double().clamp(-1, 1).acos().rad2deg()
    to = wo[:, 2].double().clamp(-1, 1).acos().rad2deg()
    return {"theta_i_deg": [round(float(ti.min()), 2), round(float(ti.max()), 2)],
            "theta_o_deg": [round(float(to.min()), 2), round(float(to.max()), 2)]}


def _describe_material(material, probe: int, directions=None) -> dict:
    """Name, isotropy, sample count and ranges; ``directions`` (wi, wo, network input) are shared
    by all the networks of an NBRDF file (the same probe directions for each, computed once)."""
    import torch

    from neuenh.data.measured import TableMaterial

    out = {"name": material.name, "isotropic": material.isotropic}
    if isinstance(material, TableMaterial):
        t = material.table
        out.update({"samples": len(t), "continuous": False, "f_r": _ranges(t.f_r), **_angles(t.wi, t.wo)})
        if material.weight is not None:
            out["weight"] = material.metadata.get("weight")
    else:
        if directions is not None:
            with torch.no_grad():
                f = material.forward(directions[2])
        else:
            _, _, f = material.samples(probe, seed=0)
        out.update({"samples": None, "continuous": True, "probe": probe, "f_r": _ranges(f)})
        if hasattr(material, "valid_fraction"):
            out["valid_bins"] = round(material.valid_fraction, 6)
    return out


def inspect_file(path: Path, probe: int) -> dict:
    import torch

    from neuenh.data.capture import read_capture
    from neuenh.data.directions import sample_directions
    from neuenh.data.exr import read_exr_channels
    from neuenh.data.formats import detect_format
    from neuenh.data.measured import load_measured
    from neuenh.data.nbrdf import load_nbrdf, network_input
    from neuenh.data.param_images import HEADER_KEY, read_parameter_exr

    if probe is not None and probe < 1:
        raise DataCommandError(f"--probe must be >= 1, got {probe}")
    kind = detect_format(path)
    if kind == "capture":
        capture = read_capture(path)
        f = torch.from_numpy(capture.values.reshape(-1, 3))
        h, w = capture.shape
        return {"file": str(path), "format": "exr_capture", "json": str(capture.path), "name": capture.name,
                "images": capture.images, "width": w, "height": h, "texels": h * w,
                "pixel_types": capture.metadata.get("pixel_types"), "quantity": capture.metadata.get("quantity"),
                "materials": [{"name": f"{capture.name}[row,col]", "count": h * w, "isotropic": False,
                               "samples": capture.images, "continuous": False, "f_r": _ranges(f),
                               **_angles(capture.wi, capture.wo)}]}
    if kind == "exr":
        channels, header = read_exr_channels(path)
        h, w = next(iter(channels.values())).shape
        out = {"file": str(path), "format": "exr", "width": w, "height": h,
               "channels": {k: str(v.dtype) for k, v in sorted(channels.items())}}
        if HEADER_KEY in header:
            image = read_parameter_exr(path)
            out["format"] = "parameter_exr"
            out["parameters"] = {k: v.shape[2] for k, v in image.params.items()}
            out["metadata"] = image.metadata
        return out
    if kind == "dataset":
        return _materialised_dataset(path)
    materials = list(load_nbrdf(path).values()) if kind == "nbrdf" else [load_measured(path)]
    directions = None
    probe = probe or (20_000 if len(materials) == 1 else 2_000)
    if kind == "nbrdf":  # isotropic networks: the same Rusinkiewicz-uniform probe for all
        wi, wo = sample_directions(probe, seed=0, anisotropic=False)
        directions = (wi, wo, network_input(wi, wo))
    out = {"file": str(path), "format": kind,
           "materials": [_describe_material(m, probe, directions) for m in materials]}
    if kind == "table":
        out["table_format"] = materials[0].metadata.get("format")
    metadata = {k: v for k, v in materials[0].metadata.items() if k not in ("path", "network", "source")}
    if kind != "nbrdf":
        out["metadata"] = metadata
    return out


def _materialised_dataset(path: Path) -> dict:
    """The summary of an .npz written by ``neuenh data sample``."""
    try:
        with np.load(path, allow_pickle=False) as npz:
            names = [str(n) for n in npz["names"]]
            train, val = npz["train_material"], npz["val_material"]
            recipe = json.loads(str(npz["recipe"]))
    except Exception as exc:  # noqa: BLE001 - numpy/zipfile/json raise many types for a corrupt file
        raise DataCommandError(f"{path}: a dataset .npz that cannot be read ({type(exc).__name__}: {exc})") from None
    return {"file": str(path), "format": "dataset", "materials": len(names), "train": int(len(train)),
            "val": int(len(val)), "names": names, "recipe": recipe}


def run_inspect(args) -> int:
    report = inspect_file(args.file, args.probe)
    print(json.dumps(report, indent=2) if args.json else _inspect_text(report))
    return 0


def _fmt3(values) -> str:
    return "(" + ", ".join(f"{v:.4g}" for v in values) + ")"


def _inspect_text(r: dict) -> str:
    fmt = r["format"] + (f" ({r['table_format']})" if r.get("table_format") else "")
    lines = [f"{r['file']}: {fmt}"]
    if r["format"] == "dataset":
        shown = ", ".join(r["names"][:6]) + (", ..." if len(r["names"]) > 6 else "")
        lines.append(f"  materialised by 'neuenh data sample': {r['materials']} materials ({shown}), "
                     f"{r['train']:,} training + {r['val']:,} validation samples")
        lines.append(f"  sources: {', '.join(s['source'] for s in r['recipe']['data'])}; val_fraction "
                     f"{r['recipe']['val_fraction']}, seed {r['recipe']['seed']}")
        return "\n".join(lines)
    if r["format"] in ("exr", "parameter_exr"):
        lines.append(f"  {r['width']}x{r['height']} pixels, channels: {', '.join(r['channels'])}")
        if "parameters" in r:
            lines.append("  parameters: " + ", ".join(f"{k} ({w})" for k, w in r["parameters"].items()))
            if r["metadata"]:
                lines.append(f"  metadata: {json.dumps(r['metadata'])}")
        return "\n".join(lines)
    if r["format"] == "exr_capture":
        lines.append(f"  capture {r['name']!r}: {r['images']} images of {r['width']}x{r['height']} texels "
                     f"({r['texels']} materials), pixels {', '.join(r['pixel_types'] or [])}, values {r['quantity']}")
    for m in r["materials"]:
        what = (f"{m['samples']} samples" if not m["continuous"] else f"continuous (ranges from {m['probe']} samples)")
        iso = "isotropic" if m["isotropic"] else "anisotropic or unknown"
        head = f"  {m['name']}" + (f" x {m['count']}" if "count" in m else "")
        lines.append(f"{head}: {iso}, {what}")
        lines.append(f"    f_r RGB min {_fmt3(m['f_r']['min'])}  max {_fmt3(m['f_r']['max'])}  "
                     f"mean {_fmt3(m['f_r']['mean'])}")
        if "theta_i_deg" in m:
            lines.append(f"    theta_i {m['theta_i_deg'][0]:.1f}..{m['theta_i_deg'][1]:.1f} deg, "
                         f"theta_o {m['theta_o_deg'][0]:.1f}..{m['theta_o_deg'][1]:.1f} deg")
        if m.get("weight"):
            w = m["weight"]
            lines.append(f"    weight {w['min']:.4g}..{w['max']:.4g} (mean {w['mean']:.4g}; not used in training)")
        if "valid_bins" in m:
            lines.append(f"    valid bins {100 * m['valid_bins']:.2f} %")
    if r.get("metadata", {}).get("description"):
        lines.append(f"  description: {r['metadata']['description']}")
    return "\n".join(lines)


# -- sample ----------------------------------------------------------------------------------
_JOB_KEYS = {"name", "model", "search", "module", "latent_dim", "train", "resources"}


def load_sample_spec(path: Path):
    """(sources, val_fraction, seed) of a dataset YAML or a job spec."""
    import yaml
    from pydantic import BaseModel, ConfigDict, Field, ValidationError

    from neuenh.data.sources import DataSource

    try:
        raw = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise DataCommandError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataCommandError(f"{path}: cannot be read ({exc})") from None
    except yaml.YAMLError as exc:
        raise DataCommandError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None
    if not isinstance(raw, dict):
        raise DataCommandError(f"{path}: a dataset spec is a mapping with a 'data:' list, got {type(raw).__name__}")
    if _JOB_KEYS & set(raw):
        from neuenh_service.orchestrator.spec import parse_spec

        try:
            spec = parse_spec(raw)
        except ValueError as exc:
            raise DataCommandError(f"{path}: {exc}") from None
        return spec.data, spec.train.val_fraction, spec.train.seed

    class DatasetSpec(BaseModel):
        model_config = ConfigDict(extra="forbid")
        data: list[DataSource] = Field(min_length=1)
        val_fraction: float = Field(0.1, ge=0.0, lt=1.0)
        seed: int = 0

    try:
        spec = DatasetSpec.model_validate(raw)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(str(p) for p in e['loc']) or 'spec'}: {e['msg']}" for e in exc.errors())
        raise DataCommandError(f"{path}: invalid dataset spec: {problems}") from None
    return spec.data, spec.val_fraction, spec.seed


def run_sample(args) -> int:
    from neuenh.data.sources import materialise

    if args.output.suffix != ".npz":
        raise DataCommandError(f"-o {args.output}: the output is an .npz file (name it *.npz)")
    if not args.output.parent.is_dir():
        raise DataCommandError(f"-o {args.output}: folder {args.output.parent} does not exist")
    sources, val_fraction, seed = load_sample_spec(args.spec)
    start = time.perf_counter()
    data = materialise(sources, val_fraction, seed)
    seconds = time.perf_counter() - start
    arrays = {f"{part}_{f}": getattr(getattr(data, part), f).numpy()
              for part in ("train", "val") for f in ("wi", "wo", "f_r", "material")}
    recipe = {"data": [s.model_dump(mode="json") for s in sources], "val_fraction": val_fraction, "seed": seed}
    arrays.update(names=np.array(data.names, dtype=str), recipe=np.array(json.dumps(recipe)))
    try:
        atomic_write(args.output, lambda tmp: savez(tmp, arrays))
    except OSError as exc:
        raise DataCommandError(f"-o {args.output}: cannot be written ({exc.strerror or exc})") from None
    report = {"output": str(args.output), "materials": len(data.names), "train": len(data.train),
              "val": len(data.val), "memory_bytes": data.nbytes,
              "file_bytes": args.output.stat().st_size, "seconds": round(seconds, 3),
              "sources": [s.source for s in sources]}
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f"{report['materials']} materials, {report['train']:,} training + {report['val']:,} validation "
              f"samples in {seconds:.1f} s; arrays {_bytes(report['memory_bytes'])} (float32 + int64 ids); "
              f"written to {args.output}")
    return 0


def _bytes(n: int) -> str:
    for unit, size in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n} B"


# -- slice -----------------------------------------------------------------------------------
_LUMA = (0.2126, 0.7152, 0.0722)  # Rec. 709 luminance weights of linear RGB


def slice_directions(view: str, resolution: int, phi_d_deg: float, theta_i_deg: float):
    """(wi, wo) (resolution², 3) float64 over the slice grid (row-major, row 0 at the bottom of
    the picture), and the axis extent and labels."""
    import torch

    from neuenh.data.directions import from_rusinkiewicz

    n = resolution
    if view == "rusinkiewicz":
        centres = (torch.arange(n, dtype=torch.float64) + 0.5) / n * (math.pi / 2)
        theta_d, theta_h = torch.meshgrid(centres, centres, indexing="ij")  # rows: theta_d, columns: theta_h
        phi_d = torch.full_like(theta_h, math.radians(phi_d_deg))
        wi, wo = from_rusinkiewicz(theta_h.reshape(-1), torch.zeros(n * n, dtype=torch.float64),
                                   theta_d.reshape(-1), phi_d.reshape(-1))
        return wi, wo, (0, 90, 0, 90), ("theta_h (deg)", "theta_d (deg)")
    coords = (torch.arange(n, dtype=torch.float64) + 0.5) / n * 2 - 1
    y, x = torch.meshgrid(coords, coords, indexing="ij")
    r2 = x * x + y * y
    z = torch.sqrt((1 - r2).clamp_min(0))
    wo = torch.stack([x, y, z], dim=-1).reshape(-1, 3)
    wo[(r2 >= 1).reshape(-1)] = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)  # outside: masked below
    t = math.radians(theta_i_deg)
    wi = torch.tensor([[math.sin(t), 0.0, math.cos(t)]], dtype=torch.float64).expand(n * n, 3)
    return wi, wo, (-1, 1, -1, 1), ("wo.x", "wo.y")


def _luminance(f: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor, n: int) -> np.ndarray:
    f = f.double()
    lum = (f @ f.new_tensor(_LUMA)).numpy().copy()
    lum[~((wi[:, 2] > 1e-6) & (wo[:, 2] > 1e-6)).numpy()] = np.nan
    return lum.reshape(n, n)


def run_slice(args) -> int:
    import torch

    from neuenh.data.formats import detect_format
    from neuenh.data.measured import TableMaterial, load_measured

    if args.resolution < 8 or args.resolution > 2048:
        raise DataCommandError(f"--resolution must be in 8..2048, got {args.resolution}")
    if args.fit_samples < 1:
        raise DataCommandError(f"--fit-samples must be >= 1, got {args.fit_samples}")
    if not 0 <= args.theta_i < 90:
        raise DataCommandError(f"--theta-i must be in [0, 90) degrees, got {args.theta_i}")
    if args.output.suffix.lower() != ".png":
        raise DataCommandError(f"-o {args.output}: the picture is a PNG (name it *.png)")
    if not args.output.parent.is_dir():
        raise DataCommandError(f"-o {args.output}: folder {args.output.parent} does not exist")
    if detect_format(args.file) == "capture":
        raise DataCommandError(f"{args.file}: a capture holds measured texels, not a continuous BRDF; slice "
                               "draws RGL, MERL or NBRDF files")
    model = None
    if args.params is not None and not args.model:
        raise DataCommandError("--params needs --model: the model the report is a fit of")
    if args.model:
        from neuenh.pretrained import load_for_fitting

        model, trained, encoder = load_for_fitting(args.model, "--model")
        fitted = read_fit_report(args.params, model) if args.params is not None else None
    material = load_measured(args.file, name=args.material)
    if isinstance(material, TableMaterial):
        raise DataCommandError(f"{args.file}: a measurement table has no continuous evaluation to slice; slice "
                               "draws RGL, MERL or NBRDF files")
    n = args.resolution
    wi, wo, extent, labels = slice_directions(args.view, n, args.phi_d, args.theta_i)
    with torch.no_grad():
        measured = _luminance(material.evaluate(wi, wo), wi, wo, n)
    panels = [(f"measured: {material.name}", measured)]
    report = {"file": str(args.file), "material": material.name, "view": args.view, "output": str(args.output)}
    if model is not None:
        label = model.name if model.state.strip("0") == "" else f"{model.name} {model.state}"
        report.update({"model": model.name, "state": model.state})
        from neuenh.render import model_brdf  # a material as its fit measured it (its capacity's model)

        if fitted is not None:
            if material.name not in fitted:
                raise DataCommandError(f"--params {args.params}: no material named {material.name!r}, the sliced "
                                       f"file's (it holds {', '.join(fitted)})")
            record = fitted[material.name]
            report.update({"params_from": str(args.params), "capacity": record.capacity})
            caption = f"{label} as fitted ({args.params.name}{f', {record.capacity}' if record.capacity else ''})"
        else:
            from neuenh.data.samples import sample_materials
            from neuenh.fit import FitOptions, fit_materials
            samples = sample_materials([material], args.fit_samples, args.seed)
            result = fit_materials(model, samples, FitOptions(epochs=args.epochs).protocol_for(model),
                                   seed=args.seed, trained=trained, encoder=encoder)
            record = result.materials.as_params(0)
            report.update({"fit_loss": result.losses[0], "fit_seconds": round(result.wall_s, 3),
                           "fit_samples": args.fit_samples})
            caption = f"{label} fit (log-L1 {result.losses[0]:.4f})"
        with torch.no_grad():
            predicted = _luminance(model_brdf(model, record)(wi.float(), wo.float()), wi, wo, n)
        panels.append((caption, predicted))
    if args.view == "rusinkiewicz":
        subtitle = f"phi_d = {args.phi_d:g} deg, phi_h = 0"
    else:
        subtitle = f"light at theta_i = {args.theta_i:g} deg, phi_i = 0; wo seen from above"
    report["range"] = _draw(args.output, panels, extent, labels, subtitle + "; grey: f_r = 0")
    print(json.dumps(report, indent=2) if args.json else f"wrote {args.output} ({material.name}, {args.view} slice"
          + (f", {panels[-1][0]}" if model is not None else "") + ")")
    return 0


def _draw(path: Path, panels, extent, labels, subtitle: str) -> list[float]:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib import colors
    except ImportError:
        raise DataCommandError("slice needs matplotlib (pip install matplotlib)") from None
    positive = np.concatenate([p[np.isfinite(p) & (p > 0)] for _, p in panels])
    if positive.size == 0:
        raise DataCommandError("the slice is zero everywhere: nothing to draw on a log scale")
    # Percentiles, not extremes: a sharp specular peak or a grazing spike would otherwise push the
    # whole body of the BRDF into the darkest colour. The colour bar shows the clipping.
    vmin, vmax = (float(v) for v in np.percentile(positive, [1.0, 99.5]))
    if not vmax > vmin:
        vmin, vmax = float(positive.min()), float(positive.max()) * 1.0001 + 1e-30
    norm = colors.LogNorm(vmin=vmin, vmax=vmax)
    cmap = plt.get_cmap("inferno").with_extremes(bad="#d0d0d0")
    with_ratio = len(panels) == 2
    count = len(panels) + with_ratio
    fig, axes = plt.subplots(1, count, figsize=(4.3 * count + 0.6, 4.3), squeeze=False, constrained_layout=True)
    axes = axes[0]
    image = None
    for ax, (title, values) in zip(axes, panels):
        shown = np.where(values > 0, values, np.nan)  # zero cannot be drawn on a log scale
        image = ax.imshow(shown, origin="lower", extent=extent, cmap=cmap, norm=norm, interpolation="nearest")
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
    fig.colorbar(image, ax=list(axes[: len(panels)]), shrink=0.85, extend="both",
                 label="luminance of f_r (1/sr), log scale")
    if with_ratio:
        floor = vmin * 1e-2  # zeros count as this, so a model that is 0 where data are not shows up
        ratio = np.log10(np.clip(panels[1][1], floor, None) / np.clip(panels[0][1], floor, None))
        limit = float(np.clip(np.nanpercentile(np.abs(ratio), 95), 0.1, 3.0)) if np.isfinite(ratio).any() else 1.0
        rcmap = plt.get_cmap("RdBu_r").with_extremes(bad="#d0d0d0")
        rimage = axes[2].imshow(ratio, origin="lower", extent=extent, cmap=rcmap, vmin=-limit, vmax=limit,
                                interpolation="nearest")
        axes[2].set_title("log10(model / measured)", fontsize=10)
        axes[2].set_xlabel(labels[0])
        axes[2].set_ylabel(labels[1])
        fig.colorbar(rimage, ax=axes[2], shrink=0.85, extend="both")
    fig.suptitle(subtitle, fontsize=10)
    try:
        fig.savefig(path, dpi=100)
    except OSError as exc:
        raise DataCommandError(f"-o {path}: cannot be written ({exc.strerror or exc})") from None
    finally:
        plt.close(fig)
    return [vmin, vmax]


__all__ = ["configure", "inspect_file", "load_sample_spec", "slice_directions"]
