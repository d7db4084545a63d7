"""Image-based captures in OpenEXR: a folder of images of a flat sample under known light and
view directions, read as one measured material per texel.

**A capture** is a folder of EXR images of a flat sample, each taken under one light direction
``wi`` and from one view direction ``wo``, plus a JSON file that lists them. Every texel (pixel)
is read as its own measured material: the values of that pixel across the images are its
apparent BRDF at the listed direction pairs (a "lumitexel"; spatially varying materials such as
OpenSVBRDF captures are many materials at once).

``capture.json`` (in the folder; any ``.json`` path may be given instead), version 1::

    {
      "version": 1,                      # optional, default 1 (the only version)
      "name": "leather",                 # optional, default: the folder's name
      "frame": "local",                  # optional, default "local" (the only frame)
      "quantity": "f_r",                 # optional: "f_r" (default) or "f_r_cos"
      "negative": "error",               # optional: "error" (default) or "clip" (to 0)
      "metadata": {...},                 # optional, free-form, carried into the materials
      "images": [                        # at least one
        {"file": "0000.exr", "wi": [0.0, 0.0, 1.0], "wo": [0.5, 0.0, 0.8660254]},
        ...
      ]
    }

* ``file``: an EXR image relative to the JSON file's folder, with (at least) the channels ``R``,
  ``G``, ``B`` (half or float; other channels such as ``A`` are ignored). All images have the
  same size. Row ``i`` of an image is its ``i``-th scanline from the top, column ``j`` its
  ``j``-th pixel from the left.
* ``wi``, ``wo``: unit vectors (|norm - 1| <= 1e-3), both above the surface (z > 0), in the
  ``local`` frame: the sample's shading frame, shared by every texel — z along the sample's
  normal (towards the light and camera), x along the image's columns (increasing ``j``) and
  y = z × x. Directions are per image (a distant light and a distant camera); per-pixel
  direction maps are not supported.
* ``quantity``: ``f_r`` — each pixel already holds f_r (RGB, 1/sr, without the cosine), the
  project's convention; ``f_r_cos`` — each pixel holds f_r · cos(theta_i), the reflected radiance
  under unit irradiance at normal incidence (what a radiometrically calibrated capture records),
  and the reader divides by ``wi.z``.
* ``negative``: a negative pixel (dark-frame subtraction noise) is an error, or clipped to 0.

Every problem — a missing JSON or image, an image the OpenEXR library cannot decode, images of
different sizes, missing ``R, G, B`` channels, non-unit directions, NaN or infinite pixels — is
a ``DataError`` that names the file and what is wrong (pixel positions as ``(row, col)``).

``read_capture(path)`` -> ``Capture``; ``capture.texel(row, col)`` is one texel as a table-like
material (``TableMaterial``: its rows are the images), ``capture.materials(region, stride)``
all of them or a sub-grid. Texel materials are named ``"<name>[row,col]"`` and carry
``metadata["texel"] = [row, col]`` (image position) and ``metadata["grid"] = [i, j]`` (position
in the region/stride grid they were taken from).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from .exr import RGB, ExrError, _rgb, read_exr_channels
from .formats import CAPTURE_JSON
from .measured import TableMaterial
from .samples import Samples

_UNIT_TOLERANCE = 1e-3

Region = tuple[int, int, int, int]  # (row0, col0, row1, col1), half-open, image coordinates


class _Image(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    file: str = Field(min_length=1)
    wi: tuple[float, float, float]
    wo: tuple[float, float, float]


class CaptureSpec(BaseModel):
    """The capture JSON (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    version: Literal[1] = 1
    name: str | None = Field(None, min_length=1)
    frame: Literal["local"] = "local"
    quantity: Literal["f_r", "f_r_cos"] = "f_r"
    negative: Literal["error", "clip"] = "error"
    metadata: dict = Field(default_factory=dict)
    images: list[_Image] = Field(min_length=1)


def capture_json_path(path: str | os.PathLike) -> Path:
    """The capture JSON of ``path`` (a capture folder or the JSON itself)."""
    path = Path(path)
    if path.is_dir():
        json_path = path / CAPTURE_JSON
        if not json_path.is_file():
            raise ExrError(f"{path}: a folder without {CAPTURE_JSON} (the capture's list of images and directions)")
        return json_path
    if not path.exists():
        raise ExrError(f"{path}: no such file or folder")
    return path


def read_capture_spec(json_path: Path) -> CaptureSpec:
    try:
        raw = json.loads(json_path.read_bytes())
    except OSError as exc:
        raise ExrError(f"{json_path}: cannot be read ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ExrError(f"{json_path}: not valid JSON ({exc})") from None
    try:
        spec = CaptureSpec.model_validate(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "(top level)"
        more = f" (and {exc.error_count() - 1} more problem(s))" if exc.error_count() > 1 else ""
        raise ExrError(f"{json_path}: {where}: {first['msg']}{more}") from None
    for k, image in enumerate(spec.images):
        for label in ("wi", "wo"):
            v = np.asarray(getattr(image, label), dtype=np.float64)
            norm = float(np.linalg.norm(v))
            if abs(norm - 1.0) > _UNIT_TOLERANCE:
                raise ExrError(f"{json_path}: images.{k} ({image.file}): {label} must be a unit vector, "
                               f"its norm is {norm:.4g}")
            if v[2] <= 0:
                raise ExrError(f"{json_path}: images.{k} ({image.file}): {label} must be above the surface "
                               f"(z > 0), got z = {v[2]:.4g}")
    return spec


# -- captures --------------------------------------------------------------------------------
@dataclass
class Capture:
    """A capture read into memory: ``values[k, i, j]`` is f_r (RGB) of image ``k`` at the held
    texel ``(rows[i], cols[j])`` (image coordinates); ``wi[k]``, ``wo[k]`` its directions."""

    name: str
    path: Path  # the capture JSON
    files: tuple[Path, ...]
    wi: torch.Tensor  # (m, 3) float32
    wo: torch.Tensor  # (m, 3) float32
    values: np.ndarray = field(repr=False)  # (m, h, w, 3) float32
    rows: np.ndarray = field(repr=False)  # (h,) image rows held
    cols: np.ndarray = field(repr=False)  # (w,) image columns held
    image_shape: tuple[int, int]
    metadata: dict = field(default_factory=dict)

    @property
    def images(self) -> int:
        return len(self.files)

    @property
    def shape(self) -> tuple[int, int]:
        """Rows and columns of texels held."""
        return len(self.rows), len(self.cols)

    def _index(self, row: int, col: int) -> tuple[int, int]:
        i = np.searchsorted(self.rows, row)
        j = np.searchsorted(self.cols, col)
        if i >= len(self.rows) or self.rows[i] != row or j >= len(self.cols) or self.cols[j] != col:
            if not (0 <= row < self.image_shape[0] and 0 <= col < self.image_shape[1]):
                raise IndexError(f"{self.path}: texel ({row}, {col}) is outside the {self.image_shape[0]}x"
                                 f"{self.image_shape[1]} image")
            raise IndexError(f"{self.path}: texel ({row}, {col}) was not read (region/stride of read_capture)")
        return int(i), int(j)

    def texel(self, row: int, col: int, grid: tuple[int, int] | None = None) -> TableMaterial:
        """The texel at image position ``(row, col)`` as a material whose rows are the images."""
        i, j = self._index(row, col)
        f = torch.from_numpy(np.ascontiguousarray(self.values[:, i, j, :]))
        name = f"{self.name}[{row},{col}]"
        table = Samples(self.wi, self.wo, f, torch.zeros(len(f), dtype=torch.long), (name,))
        metadata = {"source": "exr_capture", "path": str(self.path), "texel": [int(row), int(col)],
                    "grid": list(grid) if grid is not None else [i, j], "rows": len(f)}
        if self.metadata:
            metadata["capture"] = self.metadata
        return TableMaterial(name, table, metadata)

    def grid(self, region: Region | None = None, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Image rows and columns of the held texels in ``region`` (default: all held), every
        ``stride``-th one counted from the region's first row and column."""
        if stride < 1:
            raise ValueError(f"stride must be >= 1, got {stride}")
        if region is None:
            r0, c0, r1, c1 = int(self.rows[0]), int(self.cols[0]), int(self.rows[-1]) + 1, int(self.cols[-1]) + 1
        else:
            r0, c0, r1, c1 = _check_region(region, self.image_shape, self.path)
        rows = self.rows[(self.rows >= r0) & (self.rows < r1) & ((self.rows - r0) % stride == 0)]
        cols = self.cols[(self.cols >= c0) & (self.cols < c1) & ((self.cols - c0) % stride == 0)]
        if not len(rows) or not len(cols):
            raise ValueError(f"{self.path}: no texel read in region {region} with stride {stride}")
        return rows, cols

    def materials(self, region: Region | None = None, stride: int = 1) -> list[TableMaterial]:
        """The texels of ``region`` (``(row0, col0, row1, col1)``, half-open, image coordinates;
        default: everything read) at ``stride``, row-major, each a ``TableMaterial``."""
        rows, cols = self.grid(region, stride)
        return [self.texel(int(r), int(c), (i, j)) for i, r in enumerate(rows) for j, c in enumerate(cols)]


def _check_region(region, image_shape: tuple[int, int], path: Path) -> Region:
    if len(region) != 4:
        raise ExrError(f"{path}: a region is (row0, col0, row1, col1), got {region}")
    r0, c0, r1, c1 = (int(v) for v in region)
    h, w = image_shape
    if not (0 <= r0 < r1 <= h and 0 <= c0 < c1 <= w):
        raise ExrError(f"{path}: region {(r0, c0, r1, c1)} is not inside the {h}x{w} image "
                         "(row0 < row1 <= height, col0 < col1 <= width)")
    return r0, c0, r1, c1


def read_capture(path: str | os.PathLike, region: Region | None = None, stride: int = 1) -> Capture:
    """The capture at ``path`` (its folder or JSON). ``region`` and ``stride`` limit which texels
    are kept (and so the memory: 12 bytes per texel per image)."""
    json_path = capture_json_path(path)
    spec = read_capture_spec(json_path)
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    folder = json_path.parent
    name = spec.name or (folder.name if json_path.name == CAPTURE_JSON else json_path.stem)
    files = tuple(folder / image.file for image in spec.images)
    for k, file in enumerate(files):
        if not file.is_file():
            raise ExrError(f"{json_path}: images.{k}: {file} is listed but "
                           f"{'not a regular file' if file.exists() else 'missing'}")
    values = None
    image_shape = None
    rows = cols = None
    dtypes: set[str] = set()
    wi = np.array([image.wi for image in spec.images], dtype=np.float64)
    wo = np.array([image.wo for image in spec.images], dtype=np.float64)
    for k, file in enumerate(files):
        channels, _ = read_exr_channels(file)
        rgb = _rgb(channels, file)
        dtypes.update(str(channels[c].dtype) for c in RGB)
        if image_shape is None:
            image_shape = rgb.shape[:2]
            r0, c0, r1, c1 = _check_region(region, image_shape, json_path) if region is not None else (
                0, 0, *image_shape)
            rows = np.arange(r0, r1, stride)
            cols = np.arange(c0, c1, stride)
            values = np.empty((len(files), len(rows), len(cols), 3), dtype=np.float32)
        elif rgb.shape[:2] != image_shape:
            raise ExrError(f"{file}: image size {rgb.shape[1]}x{rgb.shape[0]} (width x height) differs from "
                           f"{files[0].name}'s {image_shape[1]}x{image_shape[0]}")
        bad = ~np.isfinite(rgb)
        if bad.any():
            row, col, c = (int(v) for v in np.argwhere(bad)[0])
            raise ExrError(f"{file}: {int(bad.any(axis=2).sum())} pixel(s) with NaN or infinite values, first at "
                           f"(row {row}, col {col}) channel {RGB[c]} = {rgb[row, col, c]}")
        crop = rgb[rows[0]:rows[-1] + 1:stride, cols[0]:cols[-1] + 1:stride]
        if (crop < 0).any():
            if spec.negative == "error":
                row, col, c = (int(v) for v in np.argwhere(crop < 0)[0])
                raise ExrError(f"{file}: negative pixel value {crop[row, col, c]:.4g} at (row {rows[row]}, col "
                               f"{cols[col]}) channel {RGB[c]} (set \"negative\": \"clip\" in {json_path.name} "
                               "to clip such values to 0)")
            crop = np.clip(crop, 0.0, None)
        if spec.quantity == "f_r_cos":
            crop = (crop / np.float32(wi[k, 2])).astype(np.float32)
        values[k] = crop
    metadata = dict(spec.metadata)
    metadata.update({"quantity": spec.quantity, "frame": spec.frame, "pixel_types": sorted(dtypes)})
    return Capture(name, json_path, files, torch.from_numpy(wi).float(), torch.from_numpy(wo).float(), values,
                   rows, cols, (int(image_shape[0]), int(image_shape[1])), metadata)
