"""Image-based captures in OpenEXR, and per-texel parameters written back as multi-channel EXR.

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

**Parameter images** (``write_parameter_exr`` / ``read_parameter_exr``): one float (or half)
channel per parameter component — a scalar ``alpha_x`` is the channel ``alpha_x``, an RGB
parameter ``rho_d`` is ``rho_d.R``, ``rho_d.G``, ``rho_d.B`` and any other vector (``normal``,
``latent``) is ``normal.0``, ``normal.1``, ``latent.0`` ... ``latent.26``. The header attribute
``neuenh`` (JSON) records the parameter order and widths and free metadata (model, state, ...);
files without it are grouped back by channel name. ``parameter_images`` lays fitted per-texel
values out on the grid. Texels that were not fitted are NaN.

``render_capture`` renders a capture of an analytical model with per-texel parameters (tests and
demos use it to make captures whose true values are known).

The OpenEXR library (PyPI ``OpenEXR``, the Academy Software Foundation bindings, >= 3.3) prints
its own diagnostics on the process's standard output and error when a file is corrupt; the
reader captures them (file descriptors 1 and 2 are redirected while a file is decoded, so output
of other threads in that short window is captured too) and puts the library's reason into the
``DataError`` instead.
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import json
import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Literal, Mapping, Sequence

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from .errors import DataError
from .measured import TableMaterial
from .samples import Samples
from .sampling import sample_directions

CAPTURE_JSON = "capture.json"
RGB = ("R", "G", "B")
HEADER_KEY = "neuenh"
_UNIT_TOLERANCE = 1e-3

Region = tuple[int, int, int, int]  # (row0, col0, row1, col1), half-open, image coordinates


class ExrError(DataError):
    """An EXR image, capture or parameter file that cannot be read or used."""


def _openexr():
    try:
        import OpenEXR
    except ImportError:  # pragma: no cover - a dependency of the project
        raise ExrError("reading EXR files needs the OpenEXR package (pip install OpenEXR)") from None
    return OpenEXR


# -- low-level EXR I/O -----------------------------------------------------------------------
@contextlib.contextmanager
def _library_messages() -> Iterator[list[str]]:
    """Capture what the OpenEXR library prints inside the block — on file descriptors 1 and 2
    (the C++ core) and on Python's ``sys.stdout`` (the bindings): it reports a corrupt file there
    besides raising. The lines are appended to the yielded list when the block ends."""
    lines: list[str] = []
    for stream in (sys.stdout, sys.stderr):  # Python's own buffered output goes out first
        with contextlib.suppress(Exception):
            stream.flush()
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no standard streams to redirect (a daemon): nothing to capture
        yield lines
        return
    python_level = io.StringIO()  # the bindings also print through Python's sys.stdout
    with tempfile.TemporaryFile() as sink:
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            with contextlib.redirect_stdout(python_level), contextlib.redirect_stderr(python_level):
                yield lines
        finally:
            _flush_c_stdio()  # output of the C/C++ side may sit in the C library's buffer
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            sink.seek(0)
            text = python_level.getvalue() + "\n" + sink.read().decode(errors="replace")
            lines.extend(line.strip() for line in text.splitlines() if line.strip())


def _flush_c_stdio() -> None:
    with contextlib.suppress(Exception):
        ctypes.CDLL(None).fflush(None)


def _reason(exc: Exception, messages: list[str]) -> str:
    """The library's most specific message (an ``EXR_ERR_...`` line), else the exception's."""
    specific = [m for m in messages if "EXR_ERR" in m]
    text = specific[-1] if specific else (str(exc) or type(exc).__name__)
    return text.split(": ", 1)[1] if text.startswith("/") and ": " in text else text


def read_exr_channels(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Every channel of the (single-part, flat) EXR image at ``path`` as an (H, W) array, and
    the header. Any problem is an ``ExrError`` naming the file."""
    path = Path(path)
    if not path.exists():
        raise ExrError(f"{path}: no such file")
    if not path.is_file():
        raise ExrError(f"{path}: not a regular file")
    OpenEXR = _openexr()
    with _library_messages() as messages:
        try:
            with open(path, "rb") as f:
                magic = f.read(4)
            if magic != b"\x76\x2f\x31\x01":
                raise ExrError(f"{path}: not an OpenEXR image (first bytes {magic!r})")
            exr = OpenEXR.File(str(path), separate_channels=True)
            header = dict(exr.header())
            channels = {name: np.asarray(c.pixels) for name, c in exr.channels().items()}
        except ExrError:
            raise
        except OSError as exc:
            raise ExrError(f"{path}: cannot be read ({exc.strerror or exc})") from None
        except Exception as exc:  # noqa: BLE001 - the bindings raise RuntimeError/ValueError/... for a corrupt file
            failure = exc
        else:
            failure = None
    if failure is not None:
        raise ExrError(f"{path}: not a readable OpenEXR image ({_reason(failure, messages)})")
    if not channels:
        raise ExrError(f"{path}: an OpenEXR image without channels")
    for name, a in channels.items():
        if a.ndim != 2:
            raise ExrError(f"{path}: channel {name!r} is not a flat 2-D image (deep or multi-part EXR?)")
    return channels, header


def write_exr_channels(path: str | os.PathLike, channels: Mapping[str, np.ndarray], *, half: bool = False,
                       attributes: Mapping[str, str] | None = None) -> Path:
    """Write (H, W) arrays as the named channels of a ZIP-compressed scanline EXR, float32 (or
    half when ``half``), atomically. ``attributes`` are extra string header attributes."""
    OpenEXR = _openexr()
    path = Path(path)
    dtype = np.float16 if half else np.float32
    data = {name: np.ascontiguousarray(np.asarray(a, dtype=np.float64).astype(dtype)) for name, a in channels.items()}
    shapes = {a.shape for a in data.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"EXR channels must be (H, W) arrays of one size, got {sorted(shapes)}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **(attributes or {})}
    tmp = path.with_name(f".{path.name}.tmp")
    OpenEXR.File(header, data).write(str(tmp))
    os.replace(tmp, path)
    return path


def write_rgb_exr(path: str | os.PathLike, rgb, *, half: bool = False) -> Path:
    """Write an (H, W, 3) image as the channels R, G, B."""
    rgb = np.asarray(rgb.detach().cpu().numpy() if isinstance(rgb, torch.Tensor) else rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"an RGB image must have shape (H, W, 3), got {rgb.shape}")
    return write_exr_channels(path, {c: rgb[:, :, k] for k, c in enumerate(RGB)}, half=half)


def read_rgb_exr(path: str | os.PathLike) -> np.ndarray:
    """The R, G, B channels of an EXR image as (H, W, 3) float32."""
    channels, _ = read_exr_channels(path)
    return _rgb(channels, Path(path))


def _rgb(channels: dict[str, np.ndarray], path: Path) -> np.ndarray:
    missing = [c for c in RGB if c not in channels]
    if missing:
        raise ExrError(f"{path}: lacks channel(s) {missing} (a capture image needs R, G, B; it has "
                       f"{sorted(channels)})")
    for c in RGB:
        if channels[c].dtype.kind != "f":
            raise ExrError(f"{path}: channel {c} must be half or float, got {channels[c].dtype}")
    return np.stack([channels[c].astype(np.float32) for c in RGB], axis=-1)


# -- the capture JSON ------------------------------------------------------------------------
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


def is_capture(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a capture folder (holding ``capture.json``) or a JSON file with an
    ``images`` list (cheap check, no validation)."""
    path = Path(path)
    if path.is_dir():
        return (path / CAPTURE_JSON).is_file()
    if not path.is_file() or path.stat().st_size > 64 << 20:
        return False
    try:
        with open(path, "rb") as f:
            head = f.read(1)
        if head != b"{":
            return False
        return isinstance(json.loads(path.read_bytes()).get("images"), list)
    except (OSError, ValueError, AttributeError):
        return False


# -- rendering a capture ---------------------------------------------------------------------
def capture_directions(n: int, seed: int = 0) -> list[tuple[list[float], list[float]]]:
    """``n`` (wi, wo) pairs drawn uniformly in Rusinkiewicz angles (anisotropic), both above the
    horizon: a light/view layout for ``render_capture``."""
    wi, wo = sample_directions(n, seed=seed, anisotropic=True)
    return [(a.tolist(), b.tolist()) for a, b in zip(wi, wo)]


def render_capture(folder: str | os.PathLike, params: Mapping[str, object], directions, *, model="ggx",
                   half: bool = False, quantity: Literal["f_r", "f_r_cos"] = "f_r", name: str | None = None,
                   state: str | None = None) -> Path:
    """Render a capture of ``model`` (a name from ``neuenh.models`` or a ``BRDFModel``) with
    per-texel parameters ``params`` (name -> (H, W) or (H, W, width) arrays) under ``directions``
    (a sequence of (wi, wo) unit 3-vectors): one EXR per pair (``0000.exr`` ...) and
    ``capture.json`` in ``folder``. Returns the JSON's path."""
    from ..models import get_model  # the models are above the data readers

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    brdf = get_model(model) if isinstance(model, str) else model
    maps = {k: _as_map(v, k) for k, v in params.items()}
    shapes = {m.shape[:2] for m in maps.values()}
    if len(shapes) != 1:
        raise ValueError(f"parameter maps must share one (H, W), got {sorted(shapes)}")
    h, w = next(iter(shapes))
    flat = {k: torch.from_numpy(m.reshape(h * w, -1)) for k, m in maps.items()}
    images = []
    for k, (wi, wo) in enumerate(directions):
        wi_t = torch.tensor(wi, dtype=torch.float64).reshape(1, 3)
        wo_t = torch.tensor(wo, dtype=torch.float64).reshape(1, 3)
        with torch.no_grad():
            f = brdf.evaluate(wi_t.expand(h * w, 3), wo_t.expand(h * w, 3), flat, state=state)
        if quantity == "f_r_cos":
            f = f * wi_t[0, 2]
        file = f"{k:04d}.exr"
        write_rgb_exr(folder / file, f.reshape(h, w, 3).numpy(), half=half)
        images.append({"file": file, "wi": [float(v) for v in wi_t[0]], "wo": [float(v) for v in wo_t[0]]})
    spec = {"version": 1, "frame": "local", "quantity": quantity, "images": images,
            "metadata": {"rendered_with": brdf.name, "state": brdf.state if state is None else state}}
    if name:
        spec["name"] = name
    json_path = folder / CAPTURE_JSON
    json_path.write_text(json.dumps(spec, indent=1))
    return json_path


def _as_map(value, name: str) -> np.ndarray:
    a = np.asarray(value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else value, dtype=np.float64)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3:
        raise ValueError(f"parameter map {name!r} must be (H, W) or (H, W, width), got shape {a.shape}")
    return a


# -- parameter images ------------------------------------------------------------------------
def parameter_channels(name: str, width: int) -> list[str]:
    """The EXR channel names of a parameter: ``name`` (width 1), ``name.R/G/B`` (an analytical
    RGB parameter, width 3) or ``name.0`` ... (any other vector, and ``latent`` always)."""
    if width == 1 and name != "latent":
        return [name]
    if width == 3 and name != "latent":
        return [f"{name}.{c}" for c in RGB]
    return [f"{name}.{k}" for k in range(width)]


@dataclass
class ParameterImage:
    """Per-texel parameters: name -> (H, W, width) float32, in file order, and the metadata."""

    params: dict[str, np.ndarray]
    metadata: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return next(iter(self.params.values())).shape[:2]


def write_parameter_exr(path: str | os.PathLike, params: Mapping[str, object], *, metadata: dict | None = None,
                        half: bool = False) -> Path:
    """Write per-texel parameters (name -> (H, W) or (H, W, width)) as one channel per component
    (see ``parameter_channels``); ``metadata`` (JSON-able) goes into the header."""
    maps = {k: _as_map(v, k) for k, v in params.items()}
    if not maps:
        raise ValueError("no parameters to write")
    channels: dict[str, np.ndarray] = {}
    layout = []
    for name, m in maps.items():
        if "." in name:
            raise ValueError(f"parameter name {name!r} must not contain '.' (it separates components)")
        names = parameter_channels(name, m.shape[2])
        layout.append({"name": name, "channels": names})
        channels.update({c: m[:, :, k] for k, c in enumerate(names)})
    header = json.dumps({"kind": "parameters", "parameters": layout, "metadata": metadata or {}})
    return write_exr_channels(path, channels, half=half, attributes={HEADER_KEY: header})


def read_parameter_exr(path: str | os.PathLike) -> ParameterImage:
    """The per-texel parameters of an EXR written by ``write_parameter_exr`` (or any EXR whose
    channels follow the naming of ``parameter_channels``)."""
    path = Path(path)
    channels, header = read_exr_channels(path)
    layout, metadata = None, {}
    if isinstance(header.get(HEADER_KEY), str):
        try:
            info = json.loads(header[HEADER_KEY])
            layout = [(p["name"], list(p["channels"])) for p in info["parameters"]]
            metadata = dict(info.get("metadata") or {})
        except (ValueError, KeyError, TypeError) as exc:
            raise ExrError(f"{path}: unreadable '{HEADER_KEY}' header attribute ({exc})") from None
    if layout is None:
        layout = _group_channels(channels)
    params = {}
    for name, names in layout:
        missing = [c for c in names if c not in channels]
        if missing:
            raise ExrError(f"{path}: parameter {name!r} lacks channel(s) {missing}")
        params[name] = np.stack([channels[c].astype(np.float32) for c in names], axis=-1)
    return ParameterImage(params, metadata)


def _group_channels(channels: Mapping[str, np.ndarray]) -> list[tuple[str, list[str]]]:
    groups: dict[str, list[str]] = {}
    for c in channels:
        base = c.rsplit(".", 1)[0] if "." in c else c
        groups.setdefault(base, []).append(c)

    def order(name: str, members: list[str]) -> list[str]:
        suffixes = [m[len(name) + 1:] if m != name else "" for m in members]
        if set(suffixes) <= set(RGB) and "" not in suffixes:
            return [f"{name}.{s}" for s in RGB if s in suffixes]
        if all(s.isdigit() for s in suffixes):
            return [f"{name}.{s}" for s in sorted(suffixes, key=int)]
        return sorted(members)

    return [(name, order(name, members)) for name, members in groups.items()]


def parameter_images(values, coords: Sequence[Sequence[int]], shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """Per-material parameter values laid out as images: ``values`` maps names to (m, width)
    tensors or arrays (or is a ``MaterialTable``: its physical values and ``latent``), ``coords``
    gives each material's (i, j) in the (H, W) = ``shape`` grid (e.g. ``metadata["grid"]`` of
    ``Capture.materials``). Texels without a material are NaN."""
    if hasattr(values, "values") and hasattr(values, "latent") and callable(values.values):
        table = values
        values = {k: v.detach() for k, v in table.values().items()}
        if table.latent_dim:
            values["latent"] = table.latent.detach()
    coords = np.asarray(coords, dtype=np.int64).reshape(-1, 2)
    h, w = shape
    if len(coords) and (coords.min() < 0 or (coords[:, 0] >= h).any() or (coords[:, 1] >= w).any()):
        raise ValueError(f"texel coordinates outside the {h}x{w} grid")
    out = {}
    for name, v in values.items():
        a = np.asarray(v.cpu().numpy() if isinstance(v, torch.Tensor) else v, dtype=np.float32)
        a = a.reshape(len(a), -1)
        if len(a) != len(coords):
            raise ValueError(f"{name}: {len(a)} materials but {len(coords)} texel coordinates")
        image = np.full((h, w, a.shape[1]), np.nan, dtype=np.float32)
        image[coords[:, 0], coords[:, 1]] = a
        out[name] = image
    return out
