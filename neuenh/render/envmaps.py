"""Procedural environment maps, so that rendering needs no image file.

``studio_environment()`` is a small photographic "studio": a soft sky gradient above the horizon,
a dim warm floor below it, and two small bright area lights with soft edges,

* the **key light**: a warm disc of angular radius 10° at ``KEY_LIGHT`` (up, to the right and in
  front of the sphere, seen from the camera of ``scene.py``), radiance 40;
* the **rim light**: a cool disc of angular radius 7° at ``RIM_LIGHT`` (behind the sphere, up and to
  the left), radiance 20, which outlines the silhouette with grazing highlights.

The values are linear HDR RGB radiance (the sky is ~0.4–0.8, the floor ~0.12), so a diffuse white
sphere comes out around 1 on its lit side at exposure 0. The image is an (H, W, 3) float32
lat-long array in the layout of ``lights.py``: row i covers the polar angle θ from +y (row 0 is
the zenith), column j the azimuth φ from +z (towards the camera) turning towards +x, and the
direction of (θ, φ) is ``(sinθ sinφ, cosθ, sinθ cosφ)``. Each texel holds the value at its centre.
Nothing is random: the same arguments always give the same image.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["KEY_LIGHT", "RIM_LIGHT", "studio_environment", "texel_directions"]


def _unit(x: float, y: float, z: float) -> tuple[float, float, float]:
    n = math.sqrt(x * x + y * y + z * z)
    return (x / n, y / n, z / n)


KEY_LIGHT = _unit(0.55, 0.7, 0.45)
"""World direction (towards the light) of the key light's centre: up, right, in front."""
RIM_LIGHT = _unit(-0.6, 0.45, -0.65)
"""World direction of the rim light's centre: up, left, behind the sphere."""

_KEY = {"direction": KEY_LIGHT, "radius_deg": 10.0, "radiance": (40.0, 38.0, 34.0)}
_RIM = {"direction": RIM_LIGHT, "radius_deg": 7.0, "radiance": (17.0, 19.0, 22.0)}
_ZENITH = np.array([0.55, 0.65, 0.8])  # sky at the zenith: a soft, slightly blue white
_HORIZON = np.array([0.8, 0.8, 0.78])  # sky at the horizon: brighter and neutral
_FLOOR = np.array([0.13, 0.12, 0.11])  # below the horizon: a dim, warm grey floor
_EDGE = 0.25  # the light discs fade out over the outer 25 % of their radius


def texel_directions(height: int, width: int) -> np.ndarray:
    """(H, W, 3) float64 world directions of the texel centres of a lat-long map (``lights.py``)."""
    if height < 1 or width < 1:
        raise ValueError(f"an environment map needs a positive size, got {height}x{width}")
    theta = (np.arange(height) + 0.5) * math.pi / height
    phi = (np.arange(width) + 0.5) * 2 * math.pi / width
    t, p = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([np.sin(t) * np.sin(p), np.cos(t), np.sin(t) * np.cos(p)], axis=-1)


def _disc(directions: np.ndarray, light: dict) -> np.ndarray:
    """(H, W, 3) radiance of a soft-edged disc light: full inside, smoothstep to 0 at its rim."""
    cos_angle = np.clip(directions @ np.asarray(light["direction"]), -1.0, 1.0)
    angle = np.degrees(np.arccos(cos_angle))
    radius = light["radius_deg"]
    # 1 inside (1 - _EDGE)·radius, 0 outside radius, smoothstep in between
    x = np.clip((radius - angle) / (_EDGE * radius), 0.0, 1.0)
    profile = x * x * (3.0 - 2.0 * x)
    return profile[..., None] * np.asarray(light["radiance"])


def studio_environment(height: int = 128, width: int = 256) -> np.ndarray:
    """The studio lat-long environment (see the module docstring) as (height, width, 3) float32.

    Every value is finite and strictly positive."""
    d = texel_directions(height, width)
    up = d[..., 1:2]  # cos θ: 1 at the zenith, 0 at the horizon, -1 at the nadir
    # sky: horizon colour blending into the zenith colour with height (smooth in elevation)
    sky = _HORIZON + (_ZENITH - _HORIZON) * np.sqrt(np.clip(up, 0.0, 1.0))
    # a soft transition band of ±3° around the horizon instead of a hard edge
    blend = np.clip(0.5 + up / (2 * math.sin(math.radians(3.0))), 0.0, 1.0)
    image = _FLOOR + (sky - _FLOOR) * blend
    image = image + _disc(d, _KEY) + _disc(d, _RIM)
    return image.astype(np.float32)
