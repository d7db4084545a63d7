"""Writing renders: linear EXR, tone-mapped PNG, and error maps.

* ``write_exr``: the linear (H, W, 3) image as an R, G, B float32 EXR (half with ``half=True``),
  through ``neuenh.data.exr.write_rgb_exr`` (ZIP compression, temporary file then rename).
* ``tonemap``: exposure (in stops) then the sRGB OETF (IEC 61966-2-1), clipped to [0, 1], 8 bits
  (the encoding ``metrics.tone_map`` gives SSIM).
* ``write_png``: the tone-mapped image as 8-bit PNG, atomically.
* ``error_map`` / ``write_error_map``: per-pixel luminance error of a render against a
  reference — absolute ``|Y - Y_ref|`` or relative ``|Y - Y_ref| / max(Y_ref, floor)`` — drawn
  with a colour map and a colour bar, atomically.

Matplotlib is used through its object API (``Figure`` + Agg canvas), never pyplot, so writing
images neither needs a display nor changes the process's backend.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from ..data.exr import write_rgb_exr
from ..files import atomic_write
from .lights import LUMINANCE
from .metrics import tone_map


def _numpy(image) -> np.ndarray:
    a = image.detach().cpu().numpy() if isinstance(image, torch.Tensor) else np.asarray(image)
    return a.astype(np.float64)


def write_exr(path: str | os.PathLike, image, *, half: bool = False) -> Path:
    """The linear (H, W, 3) ``image`` as an R, G, B EXR (float32, or half), atomically."""
    return write_rgb_exr(path, _numpy(image), half=half)


def tonemap(image, exposure: float = 0.0) -> np.ndarray:
    """(H, W, 3) uint8 sRGB of a linear image scaled by 2^exposure and clipped to [0, 1]: the
    display encoding of the SSIM protocol (``metrics.tone_map``), quantised with rounding, so a
    PNG shows what SSIM compares. Non-finite pixels are an error."""
    return np.round(tone_map(image, exposure) * 255.0).astype(np.uint8)


def write_png(path: str | os.PathLike, image, *, exposure: float = 0.0) -> Path:
    """The tone-mapped image as an 8-bit sRGB PNG, atomically."""
    from matplotlib.image import imsave

    rgb = tonemap(image, exposure)
    return atomic_write(path, lambda tmp: imsave(tmp, rgb, format="png"))


def luminance(image) -> np.ndarray:
    """(H, W) Rec. 709 luminance of a linear (H, W, 3) image."""
    return _numpy(image) @ np.asarray(LUMINANCE)


def error_map(reference, image, *, kind: Literal["absolute", "relative"] = "relative",
              floor: float = 1e-3) -> np.ndarray:
    """(H, W) luminance error of ``image`` against ``reference``: ``|Y - Y_ref|`` or, relative,
    ``|Y - Y_ref| / max(Y_ref, floor)`` (``floor`` keeps dark pixels from dominating)."""
    y_ref, y = luminance(reference), luminance(image)
    if y_ref.shape != y.shape:
        raise ValueError(f"images differ in size: {y_ref.shape} vs {y.shape}")
    diff = np.abs(y - y_ref)
    if kind == "absolute":
        return diff
    if kind == "relative":
        return diff / np.maximum(y_ref, floor)
    raise ValueError(f"kind must be 'absolute' or 'relative', got {kind!r}")


def write_error_map(path: str | os.PathLike, reference, image, *, mask=None,
                    kind: Literal["absolute", "relative"] = "relative", vmax: float | None = None,
                    title: str | None = None, cmap: str = "inferno") -> Path:
    """An error map PNG (colour map and colour bar) of ``image`` against ``reference``; pixels
    outside ``mask`` (if given) are left blank. ``vmax`` fixes the colour scale (default: the
    largest error shown)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    error = error_map(reference, image, kind=kind)
    if mask is not None:
        mask = _numpy(mask).astype(bool)
        error = np.where(mask, error, np.nan)
    finite = error[np.isfinite(error)]
    top = vmax if vmax is not None else (float(finite.max()) if finite.size and finite.max() > 0 else 1.0)
    fig = Figure(figsize=(4.2, 3.6), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    shown = ax.imshow(error, cmap=cmap, vmin=0.0, vmax=top, interpolation="nearest")
    ax.set_axis_off()
    ax.set_title(title or f"{kind} luminance error (max {float(finite.max()) if finite.size else 0:.3g})", fontsize=9)
    fig.colorbar(shown, ax=ax, fraction=0.046, pad=0.04)
    return atomic_write(path, lambda tmp: fig.savefig(tmp, format="png"))
