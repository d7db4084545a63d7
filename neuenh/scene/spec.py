"""The scene spec (``scene.yaml``): which measured materials a scene shows, how much each matters,
which models may represent them (a *ladder*, cheapest first), and how close is close enough.

    name: studio-shelf
    materials:
      - {path: ../shared/data/rgl/paper_white_rgb.bsdf, weight: 3}   # any file load_measured reads
      - {path: scans/tile.npz, name: tile}                            # a measurement table
      - {capture: scans/leather, region: [0, 0, 64, 64], stride: 16} # an EXR capture's texels
    ladder:                                # cheapest first
      - ggx                                # an analytical model
      - {rungs: enhanced-ggx}              # every rung of a shipped or searched model
      - {model: enhanced-ggx, capacity: auto}   # a model fitted at a capacity of its own
      - nbrdf                              # optional top rung: a network per material
    tolerance: {metric: log_l1, relative: 0.10}   # or {metric: delta_e_itp, absolute: 2.0}
    fit: {samples: 3000, test_samples: 3000, near_mirror: 0.5, seed: 0}
    render: {size: 64, samples_per_axis: 8, scene: ball}

* ``weight``: the material's share of the frame (or its importance), default 1; the plan's frame
  totals weigh each material by it. A capture's weight is shared by its texels equally.
* ``tolerance``: ``metric`` is held-out ``log_l1`` (the paper's loss on test samples), or a render
  metric against the measured truth under ``render`` — ``delta_e_itp`` (ITU-R BT.2124, lower is
  better) or ``ssim`` (higher is better; its error is ``1 - SSIM``). ``relative``: a rung is within
  tolerance when its error is at most the best rung's times (1 + relative); ``absolute``: at most
  that value (the best rung is taken when none is). Render metrics need materials that can be
  rendered (continuous sources: RGL, MERL, NBRDF), not tables or texels.
* A ladder entry fits its rungs at the latent capacity (the latent code and analytical parameters;
  a cost and a parameter count that are the model's own), except ``{model: M, capacity: C}``: the
  capacity of ``neuenh fit --capacity`` (``auto``, the default there: each material at the capacity
  its samples support — per-material corrections of the module weights, or an analytical model).
* Paths are relative to the scene file's folder.

``load_scene(path)`` reads and validates one, every problem a ``SceneError`` naming the field.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Literal, Union

import yaml
from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, ValidationError, field_validator, model_validator

from ..capacities import CAPACITY_CHOICES
from ..data.draws import DRAW_NEAR_MIRROR, DRAW_SAMPLES

__all__ = ["CaptureEntry", "FileEntry", "FitSpec", "ModelEntry", "RenderSpec", "RungsEntry", "SceneError",
           "SceneSpec", "Tolerance", "ladder_source", "load_scene", "parse_scene", "scene_data"]

RENDER_METRICS = ("delta_e_itp", "ssim")


class SceneError(ValueError):
    """A scene that cannot be planned; the message names the field or file and what is wrong."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FileEntry(_Strict):
    """A measured file (``neuenh.data.measured.load_measured``: RGL, MERL, NBRDF, a table)."""

    path: str = Field(min_length=1)
    name: str | None = Field(None, min_length=1, description="its name in the plan; default the file's stem "
                                                             "(an NBRDF file's network name selects it)")
    weight: float = Field(1.0, ge=0.0, allow_inf_nan=False)
    sha256: str | None = Field(None, pattern="^[0-9a-f]{64}$",
                               description="the file's content digest: checked before the file is read (a "
                                           "service sets it for the files sent with a scene)")


class CaptureEntry(_Strict):
    """An EXR capture's texels (``neuenh.data.capture``), one material each."""

    capture: str = Field(min_length=1)
    region: tuple[int, int, int, int] | None = None
    stride: int = Field(1, ge=1)
    weight: float = Field(1.0, ge=0.0, allow_inf_nan=False, description="shared by the texels equally")


MaterialEntry = Union[FileEntry, CaptureEntry]


class RungsEntry(_Strict):
    """Every rung of a shipped model or bundle folder (``neuenh.pretrained.rungs``), cheapest first."""

    rungs: str = Field(min_length=1)


class ModelEntry(_Strict):
    """A model (as a string entry names one) fitted at ``capacity`` (``neuenh.fit.FitOptions.capacity``)."""

    model: str = Field(min_length=1)
    capacity: str = Field("auto", description="auto, or one capacity of neuenh fit --capacity")

    @field_validator("capacity")
    @classmethod
    def _known_capacity(cls, capacity: str) -> str:
        if capacity not in CAPACITY_CHOICES:
            raise ValueError(f"unknown capacity {capacity!r}; choose one of {', '.join(CAPACITY_CHOICES)}")
        return capacity


def _entry_kind(entry: object) -> str | None:
    """Which kind a ladder entry is, by its type or its key (None: no kind, one error says so)."""
    if isinstance(entry, str):
        return "name"
    if isinstance(entry, dict):
        return "rungs" if "rungs" in entry else "model" if "model" in entry else None
    return "rungs" if isinstance(entry, RungsEntry) else "model" if isinstance(entry, ModelEntry) else None


# one kind per entry, told by its key, so a bad entry's error names that kind's fields alone
LadderEntry = Annotated[
    Union[Annotated[str, Tag("name")], Annotated[RungsEntry, Tag("rungs")], Annotated[ModelEntry, Tag("model")]],
    Discriminator(_entry_kind, custom_error_type="ladder_entry", custom_error_message=(
        "a ladder entry is a model's name, {rungs: MODEL} or {model: MODEL, capacity: C}"))]


def ladder_source(entry: LadderEntry) -> str:
    """What a ladder entry reads: a model's name, ``nbrdf``, or a bundle folder's path."""
    return entry if isinstance(entry, str) else entry.rungs if isinstance(entry, RungsEntry) else entry.model


class Tolerance(_Strict):
    metric: Literal["log_l1", "delta_e_itp", "ssim"] = "log_l1"
    relative: float | None = Field(None, ge=0.0, allow_inf_nan=False)
    absolute: float | None = Field(None, ge=0.0, allow_inf_nan=False)

    @model_validator(mode="after")
    def _one_kind(self) -> "Tolerance":
        if (self.relative is None) == (self.absolute is None):
            raise ValueError("give exactly one of 'relative' (to the best rung) and 'absolute'")
        return self

    @property
    def renders(self) -> bool:
        return self.metric in RENDER_METRICS

    def within(self, error: float, best: float) -> bool:
        """Whether ``error`` is close enough, the best rung's error being ``best``."""
        if self.relative is not None:
            return error <= best * (1.0 + self.relative) + 1e-12
        return error <= self.absolute


class FitSpec(_Strict):
    samples: int = Field(DRAW_SAMPLES, ge=1, description="measurements to fit each material on")
    test_samples: int = Field(3000, ge=1, description="others to measure it on (a table: at most the rest)")
    near_mirror: float = Field(DRAW_NEAR_MIRROR, ge=0.0, le=1.0, description=(
        "share of a continuous material's pairs drawn near the mirror direction, where highlights are"))
    epochs: int | None = Field(None, ge=1, description=(
        "epochs of every rung's first-order fit: Adam (an enhanced model, 300 by default), NBRDF's (300); "
        "a plain analytical rung's L-BFGS takes lbfgs_iterations"))
    lbfgs_iterations: int | None = Field(None, ge=1, description=(
        "a plain analytical rung's L-BFGS iterations per surrogate phase (300 by default)"))
    seed: int = Field(0, ge=0, lt=2**32)

    def options(self):
        """The fit options of every rung (``neuenh.fit.FitOptions``): a rung with modules is fitted at
        the latent capacity, the one its cost and its place on the ladder stand for."""
        from ..fit import FitOptions

        return FitOptions(capacity="latent", epochs=self.epochs, lbfgs_iterations=self.lbfgs_iterations)


class RenderSpec(_Strict):
    size: int = Field(64, ge=8, le=1024, description="pixels per side")
    samples_per_axis: int = Field(8, ge=1, le=64, description="light samples per pixel: its square")
    scene: Literal["ball", "sphere"] = "ball"
    seed: int = Field(0, ge=0, lt=2**32)


class SceneSpec(_Strict):
    name: str | None = None
    materials: list[Annotated[MaterialEntry, Field(union_mode="left_to_right")]] = Field(min_length=1)
    ladder: list[LadderEntry] = Field(min_length=1, description="cheapest first")
    tolerance: Tolerance = Field(default_factory=lambda: Tolerance(relative=0.1))
    fit: FitSpec = Field(default_factory=FitSpec)
    render: RenderSpec = Field(default_factory=RenderSpec)

    @field_validator("ladder")
    @classmethod
    def _ladder_names(cls, ladder):
        for i, rung in enumerate(ladder):
            if isinstance(rung, str) and not rung.strip():
                raise ValueError(f"ladder.{i}: an empty model name")
        return ladder


def _problems(exc: ValidationError) -> str:
    return "; ".join(f"{'.'.join(str(p) for p in e['loc']) or 'scene'}: {e['msg']}" for e in exc.errors())


def parse_scene(data: object, where: str = "scene") -> SceneSpec:
    if not isinstance(data, dict):
        raise SceneError(f"{where}: a scene is a mapping, got {type(data).__name__}")
    try:
        return SceneSpec.model_validate(data)
    except ValidationError as exc:
        raise SceneError(f"{where}: {_problems(exc)}") from None


def scene_data(text: str, where: str = "scene") -> object:
    """The data of a scene's YAML (or JSON) text; text that does not parse — malformed, nested deeper
    than the parser's recursion allows, an integer beyond Python's 4,300-digit conversion limit — is
    a SceneError naming ``where``."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SceneError(f"{where}: not valid YAML or JSON ({str(exc).splitlines()[0]})") from None
    except RecursionError:
        raise SceneError(f"{where}: nested too deeply to be a scene") from None
    except ValueError as exc:  # int() of a literal over sys.get_int_max_str_digits()
        raise SceneError(f"{where}: {str(exc).splitlines()[0]}") from None


def load_scene(path: str | os.PathLike) -> tuple[SceneSpec, Path]:
    """The scene at ``path`` and the folder its relative paths are relative to."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise SceneError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise SceneError(f"{path}: a folder, not a scene file") from None
    except UnicodeDecodeError as exc:
        raise SceneError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    return parse_scene(scene_data(text, str(path)), str(path)), path.resolve().parent
