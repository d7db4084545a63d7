"""Shading geometry: from local-frame directions and per-sample parameters to the quantities
every BRDF term reads.

Conventions (ARCHITECTURE §4): ``wi`` and ``wo`` are ``(n, 3)`` unit vectors in the local frame whose
z axis is the geometric normal and whose x axis is the tangent *before* rotation by ``t_theta``.
The shading normal is tilted by the two ``normal`` angles (slopes along x and y:
``n ∝ (tan a, tan b, 1)``, so ``(0, 0)`` is the geometric normal, which is the mean of the range).
The tangent is the geometric x axis carried along by the smallest rotation taking z to n, then
rotated about n by ``t_theta``.

Directions below either horizon (geometric or shading) give a BRDF of exactly zero; on those rows
the terms see normal incidence and exitance. All cosines read by the terms are clamped to
``COS_EPS`` first, so formulas are evaluated only on safe values and both values and gradients
stay finite; the mask is applied afterwards.

Everything here is written in the backend-neutral vocabulary of ``neuenh.ops`` (``xp``), so the
same geometry feeds the terms in torch, in numpy and in the exporters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping


# Smallest cosine a term ever sees. 1/(4 cos_i cos_o) stays below 1e12 (finite in float32); grazing
# directions up to 89.9 degrees (cos = 1.7e-3) are far above it and evaluated exactly.
COS_EPS = 1e-6

# The direction rows below a horizon are given (normal incidence and exitance; see shade()).
UP = (0.0, 0.0, 1.0)


@dataclass
class Shading:
    """Everything a term may read, for n samples. Directions are in the shading frame."""

    wi: Any  # Vec3: incident direction, shading frame
    wo: Any  # Vec3: outgoing direction, shading frame
    h: Any  # Vec3: half vector normalize(wi + wo), shading frame
    cos_i: Any  # (n, 1) wi.z clamped to COS_EPS
    cos_o: Any  # (n, 1) wo.z clamped to COS_EPS
    cos_h: Any  # (n, 1) h.z clamped to COS_EPS
    cos_d: Any  # (n, 1) wi.h (= wo.h) clamped to [COS_EPS, 1]
    params: Mapping[str, Any]  # physical parameter values, each (n, width) (or constants)
    above: Any  # (n, 1) bool: both directions above both horizons
    xp: Any  # the math vocabulary the values belong to (neuenh.ops)

    @classmethod
    def of_params(cls, params: Mapping[str, Any], xp) -> "Shading":
        """What a term that reads no direction sees: the parameters alone."""
        return cls(None, None, None, None, None, None, None, params, None, xp)


def shading_frame(xp, normal_angles, t_theta) -> tuple[Any, Any, Any]:
    """Orthonormal (tangent, bitangent, normal) Vec3s in the local frame, from the ``normal``
    slope angles (``n ∝ (tan a, tan b, 1)``) and the tangent rotation ``t_theta``."""
    a, b = xp.tan(xp.component(normal_angles, 0)), xp.tan(xp.component(normal_angles, 1))
    inv_len = 1.0 / xp.sqrt(a * a + b * b + 1.0)
    nx, ny, nz = a * inv_len, b * inv_len, inv_len
    # The smallest rotation taking z to n maps x and y to these (nz > 0 for every allowed tilt).
    k = 1.0 / (1.0 + nz)
    t0 = (1.0 - nx * nx * k, -nx * ny * k, -nx)
    b0 = (-nx * ny * k, 1.0 - ny * ny * k, -ny)
    normal = xp.vec3(nx, ny, nz)
    if t_theta is None:
        return xp.vec3(*t0), xp.vec3(*b0), normal
    # Rotated about n by t_theta: t = c t0 + s b0, b = c b0 - s t0, written per component. Scalar
    # arithmetic, because torch.compile cannot trace a tensor times a Vec3 made in an inner function:
    # it split the compiled training step in six (docs/BENCHMARKS.md, "The compiled training step").
    c, s = xp.cos(t_theta), xp.sin(t_theta)
    t = xp.vec3(*(c * u + s * v for u, v in zip(t0, b0)))
    b = xp.vec3(*(c * v - s * u for u, v in zip(t0, b0)))
    return t, b, normal


def frame_of(xp, params: Mapping[str, Any]) -> tuple[Any, Any, Any] | None:
    """``shading_frame`` of a model's parameters (per sample or per material alike), or None for a
    model without a ``normal`` parameter (the local frame is the shading frame)."""
    if "normal" not in params or params["normal"] is None:
        return None
    return shading_frame(xp, params["normal"], params.get("t_theta"))


def to_frame(xp, w, frame: tuple[Any, Any, Any]):
    """Local-frame Vec3 -> the same direction in the frame (tangent, bitangent, normal)."""
    t, b, n = frame
    return xp.vec3(xp.dot(w, t), xp.dot(w, b), xp.dot(w, n))


def shade(xp, wi, wo, wi_s, wo_s, params: Mapping[str, Any]) -> Shading:
    """The shading context from the directions in the local frame (``wi``, ``wo``: for the
    geometric horizon) and in the shading frame (``wi_s``, ``wo_s``)."""
    above = (wi.z > 0) & (wo.z > 0) & (wi_s.z > 0) & (wo_s.z > 0)
    # Rows below a horizon are masked to zero, but their terms are still evaluated (and
    # differentiated): give them normal incidence and exitance. Otherwise a half vector pointing
    # into the surface (e.g. wi = wo = -n) leaves h_z clamped to COS_EPS with h_x = h_y = 0, GGX's
    # D = 1/(pi a_x a_y COS_EPS^4) and its derivative overflow in float32, and the mask's zero
    # gradient times that inf poisons every parameter with NaN.
    wi_s, wo_s = xp.where(above, wi_s, UP), xp.where(above, wo_s, UP)
    # Both directions are now above the shading horizon, so wi + wo never vanishes.
    h = xp.normalize(wi_s + wo_s)
    return Shading(
        wi=wi_s,
        wo=wo_s,
        h=h,
        cos_i=xp.clamp(wi_s.z, COS_EPS),
        cos_o=xp.clamp(wo_s.z, COS_EPS),
        cos_h=xp.clamp(h.z, COS_EPS),
        cos_d=xp.clamp(xp.dot(wi_s, h), COS_EPS, 1.0),
        params=params,
        above=above,
        xp=xp,
    )


def make_shading(wi, wo, params: Mapping[str, Any], xp, frame: tuple[Any, Any, Any] | None = None) -> Shading:
    """Build the shading context on the backend ``xp`` (``neuenh.ops``: ``TORCH``, ``NUMPY``, an
    exporter's). ``wi``, ``wo``: (n, 3) local-frame arrays (or Vec3s of ``xp``);
    ``params`` are physical values already broadcast to (n, width). ``frame``: the shading frame of
    each sample when the caller has it (``shading_frame`` of ``params``, e.g. built once per material
    and gathered); by default it is built here from ``params``."""
    wi, wo = xp.as_vec3(wi), xp.as_vec3(wo)
    frame = frame_of(xp, params) if frame is None else frame
    if frame is None:
        return shade(xp, wi, wo, wi, wo, params)
    return shade(xp, wi, wo, to_frame(xp, wi, frame), to_frame(xp, wo, frame), params)
