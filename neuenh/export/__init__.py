"""Exporters: fitted materials of a model, in a renderer's own format (ARCHITECTURE §2).

Each format is a module with one entry point,

    write(model: BRDFModel, materials: Mapping[str, MaterialParams], out_dir: Path) -> list[Path]

that writes the files for ``materials`` (name -> the material's ``neuenh.materials.MaterialParams``:
its analytical values, latent code and corrections, as ``BRDFModel.specialize`` takes them) into
``out_dir`` and returns their paths. What is exported is the specialized evaluator (``neuenh.specialize``): the
material's parameters and the modules' weights folded in, f_r without the cosine factor, zero below
either horizon. Every format is checked by running the artifact in its real runtime (tests):

* ``glsl`` (``neuenh.export.glsl``): GLSL 4.50 functions, run on Mesa's llvmpipe;
* ``onnx`` (``neuenh.export.onnx``): ONNX graphs, run with onnxruntime;
* ``mitsuba`` (``neuenh.export.mitsuba``): a Mitsuba 3 BSDF plugin (Python, Dr.Jit) and a scene per
  material, run in Mitsuba (its chi-square test, against its built-in GGX).

``export_nbrdf`` writes per-material NBRDF networks (a scene plan's ``nbrdf`` rung) in the same three
formats, with the same names and conventions (``neuenh.export.nbrdf``).

The runtimes are the optional extra ``neuenh[export]``; this package imports them only inside the
format that needs them. Imports neither Ray, FastAPI nor SQL.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path
from typing import TYPE_CHECKING, Mapping

if TYPE_CHECKING:
    from ..materials import MaterialParams
    from ..study.nbrdf_fit import NBRDFNetwork

FORMATS = ("glsl", "onnx", "mitsuba")


class MissingRuntime(ValueError):
    """A format whose writer needs a package of the ``neuenh[export]`` extra that is not installed."""


class ExportError(ValueError):
    """What was asked cannot be exported as asked (an unknown format, no materials, two material
    names that become one file name); the message names the materials."""


def export(model, materials: Mapping[str, MaterialParams], fmt: str, out_dir: Path) -> list[Path]:
    """Write ``materials`` of ``model`` in format ``fmt`` into ``out_dir``; returns the files."""
    return _writer(fmt, materials).write(model, materials, Path(out_dir))


def export_nbrdf(networks: Mapping[str, NBRDFNetwork], fmt: str, out_dir: Path) -> list[Path]:
    """Write per-material NBRDF ``networks`` (name -> network, a scene plan's ``nbrdf`` rung) in
    format ``fmt`` into ``out_dir`` (``neuenh.export.nbrdf``); returns the files."""
    return _writer(fmt, networks).write_nbrdf(networks, Path(out_dir))


def _writer(fmt: str, materials: Mapping):
    """The format's module, once the request is known to be one it can write."""
    if fmt not in FORMATS:
        raise ExportError(f"unknown export format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if not materials:
        raise ExportError("nothing to export: no materials")
    try:
        return importlib.import_module(f"{__name__}.{fmt}")
    except ImportError as exc:
        raise MissingRuntime(f"the {fmt} export needs {exc.name or 'a package'}, which is not installed "
                             "(pip install 'neuenh[export]')") from None


def file_names(materials, suffix: str) -> dict[str, str]:
    """Each material's file name stem (``identifier``), refusing two that collide."""
    names: dict[str, str] = {}
    for material in materials:
        name = identifier(material)
        if name in names:
            raise ExportError(f"materials {names[name]!r} and {material!r} both export as {name}{suffix}; rename one")
        names[name] = material
    return names


def identifier(material: str) -> str:
    """A material name as an identifier (file names, GLSL symbols): other characters become ``_``,
    runs of ``_`` one (GLSL reserves ``__``), a leading digit gets ``m`` before it."""
    name = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", material)).strip("_") or "material"
    return f"m{name}" if name[0].isdigit() else name
