"""Image and sample metrics: SSIM, ΔE_ITP and the held-out log-L1.

The paper compares renders with SSIM and ΔE_ITP (reported as ΔE_ITP × 10³) and fits with the
log-L1 loss. The two image metrics come from well-kept libraries — ``skimage.metrics`` for SSIM,
``colour`` (colour-science) for ICtCp and ΔE_ITP — and this module only fixes, once, *how* linear
HDR renders are handed to them, so every table in the project is computed the same way.

Protocols
---------
Inputs are linear, scene-referred RGB with BT.709 / sRGB primaries (what the renderer writes to
EXR), shaped ``(H, W, 3)`` (``(..., 3)`` for ΔE_ITP), numpy arrays or CPU torch tensors.

**SSIM** (Wang, Bovik, Sheikh & Simoncelli 2004, "Image quality assessment: from error visibility
to structural similarity", IEEE TIP 13(4)):

1. tone-map both images identically: multiply by ``2**exposure`` (default 0 stops: linear 1.0 is
   display white), clip negatives to 0, apply the sRGB OETF (IEC 61966-2-1, via
   ``colour.models.eotf_inverse_sRGB``) and clip to [0, 1];
2. ``skimage.metrics.structural_similarity(..., channel_axis=-1, data_range=1.0,
   gaussian_weights=True, sigma=1.5, use_sample_covariance=False)`` — the settings skimage names
   as matching Wang et al. (11 × 11 Gaussian window, K1 = 0.01, K2 = 0.03); the SSIM of each
   channel is averaged;
3. with a ``mask`` (True = pixel counts), masked-out pixels of *both* tone-mapped images are set to
   black before step 2, so nothing outside the mask can change the result, and the value is the
   mean of the full SSIM map over the masked pixels and the three channels. As skimage does for
   the unmasked mean, the border ring of 5 pixels (half the window) is excluded, so an all-True
   mask gives exactly the unmasked value.

**ΔE_ITP** (ITU-R BT.2124, on ICtCp of ITU-R BT.2100):

1. clip negatives to 0 (a display emits no negative light), convert linear BT.709 to linear
   BT.2020 (``colour.RGB_to_RGB``, same D65 white, no chromatic adaptation);
2. put the images on an absolute scale: linear 1.0 is ``peak_nits`` cd/m² (default 100, the SDR
   reference white), as the PQ transfer function is absolute (its range ends at 10 000 cd/m²;
   brighter values are extrapolated by the same formula);
3. ``colour.RGB_to_ICtCp(..., method="ITU-R BT.2100-2 PQ")`` (BT.2100 LMS matrix, PQ inverse EOTF
   with ``L_p = 10000``, ICtCp matrix) and ``colour.difference.delta_E_ITP``, i.e.
   ``720 · sqrt(ΔI² + (ΔCt / 2)² + ΔCp²)`` per pixel; the result is the mean over the (masked)
   pixels.

The functions return the plain ΔE_ITP (1 ≈ one just-noticeable difference), which is what
``neuenh render`` and ``neuenh report`` show. The paper's column is "ΔE_ITP × 10³" with values near
1–2 for visibly different renders: that only fits a much dimmer absolute luminance than BT.2124's
(which it does not state), so its numbers compare with ours in ranking, not in value.

**Held-out log-L1**: the metric *is* the paper's loss, :func:`neuenh.train.log_l1`;
:func:`log_l1` here only accepts numpy or torch inputs, validates them and returns the mean as a
float.
"""

from __future__ import annotations

import importlib
from typing import Any

import numpy as np
import torch

from neuenh import train as _train

__all__ = ["delta_e_itp", "delta_e_itp_map", "ictcp", "log_l1", "ssim", "tone_map"]

DEFAULT_PEAK_NITS = 100.0
"""Luminance (cd/m²) at which linear RGB 1.0 is shown for ΔE_ITP: the SDR reference white."""

# Wang et al. 2004 settings, as named in skimage's documentation of structural_similarity.
_SSIM_KWARGS = {"gaussian_weights": True, "sigma": 1.5, "use_sample_covariance": False}
_SSIM_WINDOW = 11  # skimage: 2 * int(truncate * sigma + 0.5) + 1 with truncate = 3.5, sigma = 1.5
_SSIM_PAD = (_SSIM_WINDOW - 1) // 2


def _colour() -> Any:
    """colour-science, imported on first use: importing it costs ~2 s of CPU (it loads scipy and
    matplotlib), which every process that imports the renderer, the planner or the API would
    otherwise pay before its first metric (each `neuenh` command, each service start)."""
    return importlib.import_module("colour")


def _structural_similarity(*args: Any, **kwargs: Any) -> Any:
    """``skimage.metrics.structural_similarity``, imported on first use (as :func:`_colour`)."""
    return importlib.import_module("skimage.metrics").structural_similarity(*args, **kwargs)


def _as_array(x: Any, name: str) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    try:
        array = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name} must be a numeric array: {error}") from None
    if not np.all(np.isfinite(array)):
        bad = int(np.size(array) - np.count_nonzero(np.isfinite(array)))
        raise ValueError(f"{name} has {bad} non-finite value(s) (NaN or Inf)")
    return array


def _check_pair(reference: Any, test: Any, image: bool) -> tuple[np.ndarray, np.ndarray]:
    ref = _as_array(reference, "reference")
    tst = _as_array(test, "test")
    if ref.shape != tst.shape:
        raise ValueError(f"shape mismatch: reference {ref.shape} vs test {tst.shape}")
    if image and (ref.ndim != 3 or ref.shape[-1] != 3):
        raise ValueError(f"images must be (H, W, 3) linear RGB, got shape {ref.shape}")
    if not image and (ref.ndim < 1 or ref.shape[-1] != 3):
        raise ValueError(f"colours must be (..., 3) linear RGB, got shape {ref.shape}")
    return ref, tst


def _check_mask(mask: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    if mask is None:
        return None
    if isinstance(mask, torch.Tensor):
        mask = mask.detach().cpu().numpy()
    mask = np.asarray(mask)
    if mask.dtype != np.bool_:
        raise ValueError(f"mask must be boolean (True = pixel counts), got dtype {mask.dtype}")
    if mask.shape != shape:
        raise ValueError(f"mask shape {mask.shape} does not match the image's pixels {shape}")
    if not mask.any():
        raise ValueError("empty mask: no pixel is selected")
    return mask


def tone_map(image: Any, exposure: float = 0.0) -> np.ndarray:
    """The SSIM protocol's display encoding: ``clip(sRGB_OETF(max(image · 2**exposure, 0)), 0, 1)``."""
    linear = np.maximum(_as_array(image, "image") * 2.0**exposure, 0.0)
    return np.clip(_colour().models.eotf_inverse_sRGB(linear), 0.0, 1.0)


def ssim(reference: Any, test: Any, mask: Any = None, exposure: float = 0.0) -> float:
    """SSIM (Wang et al. 2004) of two linear HDR ``(H, W, 3)`` images, 1 = identical.

    Both are tone-mapped with :func:`tone_map` (same ``exposure``, in stops), then compared by
    ``skimage.metrics.structural_similarity`` with Wang et al.'s settings (Gaussian 11 × 11 window,
    sigma 1.5, ``data_range=1``, per channel, averaged). With a boolean ``(H, W)`` ``mask``, pixels
    outside it are blacked out in both images and the SSIM map is averaged over the masked pixels
    (border ring of 5 pixels excluded, as skimage does). See the module docstring.
    """
    ref, tst = _check_pair(reference, test, image=True)
    height, width = ref.shape[:2]
    if min(height, width) < _SSIM_WINDOW:
        raise ValueError(f"images must be at least {_SSIM_WINDOW}x{_SSIM_WINDOW} pixels for SSIM, got {height}x{width}")
    mask = _check_mask(mask, ref.shape[:2])
    a, b = tone_map(ref, exposure), tone_map(tst, exposure)
    if mask is None:
        return float(_structural_similarity(a, b, channel_axis=-1, data_range=1.0, **_SSIM_KWARGS))
    a[~mask] = 0.0
    b[~mask] = 0.0
    _, full = _structural_similarity(a, b, channel_axis=-1, data_range=1.0, full=True, **_SSIM_KWARGS)
    inner = np.zeros_like(mask)
    inner[_SSIM_PAD : height - _SSIM_PAD, _SSIM_PAD : width - _SSIM_PAD] = True
    selected = mask & inner
    if not selected.any():
        raise ValueError(f"empty mask: every masked pixel lies in the {_SSIM_PAD}-pixel border SSIM excludes")
    return float(full[selected].mean())


def ictcp(rgb: Any, peak_nits: float = DEFAULT_PEAK_NITS) -> np.ndarray:
    """ICtCp (BT.2100 PQ) of linear BT.709 RGB ``(..., 3)`` with linear 1.0 = ``peak_nits`` cd/m²."""
    if not peak_nits > 0:
        raise ValueError(f"peak_nits must be positive, got {peak_nits}")
    linear = np.maximum(_as_array(rgb, "rgb"), 0.0)
    colour = _colour()
    bt2020 = colour.RGB_to_RGB(
        linear,
        colour.RGB_COLOURSPACES["ITU-R BT.709"],
        colour.RGB_COLOURSPACES["ITU-R BT.2020"],
        chromatic_adaptation_transform=None,
    )
    return colour.RGB_to_ICtCp(bt2020 * peak_nits, method="ITU-R BT.2100-2 PQ", L_p=10000)


def delta_e_itp_map(reference: Any, test: Any, peak_nits: float = DEFAULT_PEAK_NITS) -> np.ndarray:
    """Per-pixel ΔE_ITP (BT.2124) of linear BT.709 colours ``(..., 3)``, shape ``(...)``; an error map."""
    ref, tst = _check_pair(reference, test, image=False)
    return np.asarray(_colour().difference.delta_E_ITP(ictcp(ref, peak_nits), ictcp(tst, peak_nits)), dtype=np.float64)


def delta_e_itp(reference: Any, test: Any, mask: Any = None, peak_nits: float = DEFAULT_PEAK_NITS) -> float:
    """Mean ΔE_ITP (ITU-R BT.2124) of two linear BT.709 images or colour arrays ``(..., 3)``.

    Linear 1.0 is shown at ``peak_nits`` cd/m² (default 100); ICtCp and ΔE_ITP are computed by
    colour-science (see the module docstring). ``mask`` (boolean, shape ``(...)``) restricts the
    mean to the selected pixels. Returns the plain ΔE_ITP (see the module doc on the paper's units).
    """
    ref, tst = _check_pair(reference, test, image=False)
    mask = _check_mask(mask, ref.shape[:-1])
    errors = delta_e_itp_map(ref, tst, peak_nits)
    return float(errors.mean() if mask is None else errors[mask].mean())


def log_l1(f_true: Any, f_pred: Any, cos_i: Any) -> float:
    """Mean paper log-L1 on held-out samples, via :func:`neuenh.train.log_l1` (not re-implemented).

    ``mean |log(1 + f_true·cos_i) − slog1p(f_pred·cos_i)|`` over samples and RGB, where ``slog1p``
    is ``sign·log1p(|x|)`` so negative predictions stay finite. ``f_true`` and ``f_pred`` are
    ``(n, 3)`` BRDF values without the cosine; ``cos_i`` is either the ``(n,)`` / ``(n, 1)``
    cosines of the incident directions with the ground-truth normal, or the ``(n, 3)`` incident
    directions ``wi`` in the local frame (z = normal), as stored with the samples. Negative
    cosines count as 0. Argument order matters: the loss treats truth and prediction differently.
    """
    truth = _as_array(f_true, "f_true")
    pred = _as_array(f_pred, "f_pred")
    cosine = _as_array(cos_i, "cos_i")
    if truth.ndim != 2 or truth.shape[1] != 3:
        raise ValueError(f"f_true must be (n, 3), got shape {truth.shape}")
    if pred.shape != truth.shape:
        raise ValueError(f"shape mismatch: f_true {truth.shape} vs f_pred {pred.shape}")
    n = truth.shape[0]
    if n == 0:
        raise ValueError("no samples: f_true is empty")
    if cosine.shape in ((n,), (n, 1)):
        wi = np.zeros((n, 3))
        wi[:, 2] = cosine.reshape(n)
    elif cosine.shape == (n, 3):
        wi = cosine
    else:
        raise ValueError(f"cos_i must be (n,), (n, 1) cosines or (n, 3) directions wi with n = {n}, got shape {cosine.shape}")
    per_sample = _train.log_l1(torch.from_numpy(pred), torch.from_numpy(truth), torch.from_numpy(wi))
    return float(per_sample.mean())
