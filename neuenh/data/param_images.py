"""Per-texel parameters written back as multi-channel OpenEXR (and read again).

**Parameter images** (``write_parameter_exr`` / ``read_parameter_exr``): one float (or half)
channel per parameter component — a scalar ``alpha_x`` is the channel ``alpha_x``, an RGB
parameter ``rho_d`` is ``rho_d.R``, ``rho_d.G``, ``rho_d.B`` and any other vector (``normal``,
``latent``) is ``normal.0``, ``normal.1``, ``latent.0`` ... ``latent.26``. The header attribute
``neuenh`` (JSON) records the parameter order and widths and free metadata (model, state, ...);
files without it are grouped back by channel name. ``parameter_images`` lays fitted per-texel
values out on the grid. Texels that were not fitted are NaN.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import torch

from .exr import RGB, ExrError, read_exr_channels, write_exr_channels
from ..materials import LATENT_NAME

HEADER_KEY = "neuenh"


def as_parameter_map(value, name: str) -> np.ndarray:
    a = np.asarray(value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else value, dtype=np.float64)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3:
        raise ValueError(f"parameter map {name!r} must be (H, W) or (H, W, width), got shape {a.shape}")
    return a


def parameter_channels(name: str, width: int) -> list[str]:
    """The EXR channel names of a parameter: ``name`` (width 1), ``name.R/G/B`` (an analytical
    RGB parameter, width 3) or ``name.0`` ... (any other vector, and ``latent`` always)."""
    if width == 1 and name != LATENT_NAME:
        return [name]
    if width == 3 and name != LATENT_NAME:
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
    maps = {k: as_parameter_map(v, k) for k, v in params.items()}
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
            values[LATENT_NAME] = table.latent.detach()
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
