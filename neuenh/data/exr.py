"""OpenEXR images in and out: named float/half channels, RGB images, and errors that name the file
and the library's reason (``ExrError``, a ``DataError``). Captures (``capture``) and parameter
images (``param_images``) are built on these.

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
import os
import sys
import tempfile
from pathlib import Path
from typing import Iterator, Mapping

import numpy as np
import torch

from ..files import atomic_write
from .errors import DataError

RGB = ("R", "G", "B")


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
    return atomic_write(path, lambda tmp: OpenEXR.File(header, data).write(str(tmp)))


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
