"""Captures with known truth for the tests: an analytical model with per-texel parameters rendered
into a capture folder (one EXR per direction pair and ``capture.json``), read back by
``neuenh.data.capture``."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Literal, Mapping

import torch

from neuenh.data.capture import CAPTURE_JSON
from neuenh.data.directions import sample_directions
from neuenh.data.exr import write_rgb_exr
from neuenh.data.param_images import as_parameter_map
from neuenh.models import get_model


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
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    brdf = get_model(model) if isinstance(model, str) else model
    maps = {k: as_parameter_map(v, k) for k, v in params.items()}
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
