"""Per-material NBRDF networks (the scene planner's ``nbrdf`` rung) in every export format.

A network (``neuenh.study.nbrdf_fit.NBRDFNetwork``; Sztrajman, Rainer, Ritschel, Weyrich 2021, "Neural
BRDF Representation and Importance Sampling", CGF 40(6)) is

    x   = [sin theta_h, 0, cos theta_h, sin theta_d cos phi_d, sin theta_d sin phi_d, cos theta_d]
    f_r = max(exp(W3 relu(W2 relu(W1 x + b1) + b2) + b3) - 1, 0),   0 unless both directions are above,

with phi_d folded into [0, pi) (``neuenh.data.nbrdf.fold_phi_d``). Its inputs are written here once
in the backend-neutral vocabulary (``neuenh.ops``: ``network_inputs``), so the GLSL function, the ONNX
graph and the Mitsuba plugin run the same formula, and the second input, always 0, is dropped with its
column of W1 (``folded_network``). Each format writes the network with the code it writes modules
with (``FoldedModule``, ReLU as a LeakyReLU of slope 0):

* ``glsl``: ``NAME.glsl``, ``vec3 neuenh_NAME_brdf(vec3 wi, vec3 wo)`` (and ``neuenh_brdf``);
* ``onnx``: ``NAME.onnx``, inputs ``wi``, ``wo`` (n, 3), output ``f_r`` (n, 3);
* ``mitsuba``: ``NAME.json`` (the weights and a sampling lobe, ``sampling_lobe``) and ``NAME.xml``,
  read by the same ``neuenh`` BSDF plugin as every other exported material.

Conventions are those of every exported material: f_r without the cosine factor, ``wi`` (the light)
and ``wo`` unit vectors in the local frame, z the normal; an NBRDF network is isotropic and has no
shading frame of its own.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable

import torch

from ..specialize import FoldedModule

if TYPE_CHECKING:
    from ..study.nbrdf_fit import NBRDFNetwork

# Below this sin(theta_h) the half vector is the normal, where phi_h is atan2(0, 0) = 0, as in
# ``neuenh.data.directions.to_rusinkiewicz`` (float32's smallest normal number is 1.2e-38).
TINY = 1e-30

# Rec. 709 luminance of an RGB value (the sampling lobe is fitted to one channel).
LUMINANCE = (0.2126, 0.7152, 0.0722)


def folded_network(net: NBRDFNetwork) -> FoldedModule:
    """The network's three layers as a module the exporters write (weights (out, in) float32), the
    first layer without the column of the always-zero second input (``network_inputs``)."""
    linear = [m for m in net.layers if isinstance(m, torch.nn.Linear)]
    layers = [(m.weight.detach().float().clone(), m.bias.detach().float().clone()) for m in linear]
    first, bias = layers[0]
    layers[0] = (torch.cat([first[:, :1], first[:, 2:]], dim=1), bias)
    return FoldedModule("nbrdf", tuple(layers), 0.0)  # LeakyReLU of slope 0: the network's ReLU


def network_inputs(xp, wi, wo) -> list:
    """The network's inputs at unit directions ``wi``, ``wo`` (``xp`` Vec3s), the always-zero second one
    left out: [sin theta_h, cos theta_h, d_x, d_y, d_z], d the difference vector (Rusinkiewicz 1998:
    ``wi`` rotated by -phi_h about the normal, then by -theta_h about the bitangent) with phi_d folded
    into [0, pi) — the values ``neuenh.data.nbrdf.network_input`` computes from angles, computed from the
    vectors (no inverse trigonometry, no cancellation near the peak)."""
    h = xp.normalize(wi + wo)
    sin_h = xp.sqrt(h.x * h.x + h.y * h.y)  # sin theta_h as |h_xy|: exact near theta_h = 0, where 1 - cos^2 is not
    inverse = 1.0 / xp.maximum(sin_h, TINY)
    tilted = sin_h > 0.0
    cos_p = xp.where(tilted, h.x * inverse, 1.0)  # cos phi_h; phi_h = 0 at the normal
    sin_p = xp.where(tilted, h.y * inverse, 0.0)  # sin phi_h
    x = cos_p * wi.x + sin_p * wi.y  # wi rotated by -phi_h about the normal
    y = cos_p * wi.y - sin_p * wi.x
    dx = h.z * x - sin_h * wi.z  # ... then by -theta_h about the bitangent: d = (dx, y, dz)
    dz = sin_h * x + h.z * wi.z
    # phi_d = atan2(y, dx) folded into [0, pi): +pi below 0 (y < 0, or y = -0 with dx < 0, where atan2
    # gives -pi), -pi at pi (y = +0 with dx < 0); either way d_x and d_y change sign
    flip = (y < 0.0) | ((y <= 0.0) & (dx < 0.0))
    return [sin_h, h.z, xp.where(flip, -dx, dx), xp.where(flip, -y, y), dz]


def brdf(xp, wi, wo, mlp: Callable[[list], Any]) -> Any:
    """f_r of the network ``mlp`` (the format's own call of ``folded_network``: a list of inputs ->
    the RGB output) at ``wi``, ``wo``, before the horizon mask (``above``) and the clamp at 0, which
    the format applies as it does for every material."""
    return xp.exp(mlp(network_inputs(xp, wi, wo))) - 1.0  # the network predicts log(1 + f_r)


def above(wi, wo) -> Any:
    """Where f_r is not 0: both directions above the horizon."""
    return (wi.z > 0.0) & (wo.z > 0.0)


def sampling_lobe(net: NBRDFNetwork) -> tuple[float, float]:
    """(alpha, p_spec) of the isotropic GGX-and-cosine mixture the Mitsuba plugin samples an NBRDF
    material with (``neuenh.export.mitsuba``), read off the network's retro-reflection profile
    (wi = wo at theta from the normal, so theta_h = theta, theta_d = 0), in luminance:

    * the diffuse level ``floor``: the profile's least value beyond 60 degrees;
    * alpha: the GGX whose D falls to half its peak where the profile's excess over ``floor`` does
      (D(t) / D(0) = 1/2 at sin^2 t = alpha^2 (sqrt 2 - cos^2 t));
    * p_spec: the specular albedo's share, rho_s = 4 pi alpha^2 excess(0) (GGX at normal incidence:
      f = rho_s D(0) / 4 with D(0) = 1 / (pi alpha^2)) against rho_d = pi floor, kept in [0.1, 0.9]
      as for every material.

    It only steers where samples go: the plugin's weight is f_r cos / pdf of this very mixture, so the
    estimate is unbiased whatever the lobe (a poor lobe costs noise, not correctness)."""
    theta = math.radians(85.0) * torch.linspace(0.0, 1.0, 257, dtype=torch.float64) ** 2  # fine near the peak
    w = torch.stack([torch.sin(theta), torch.zeros_like(theta), torch.cos(theta)], dim=-1).float()
    profile = net.evaluate(w, w).double() @ torch.tensor(LUMINANCE, dtype=torch.float64)
    floor = float(profile[theta > math.radians(60.0)].min().clamp_min(0.0))
    excess = (profile - floor).clamp_min(0.0)
    peak = float(excess[0])
    below = torch.nonzero(excess < 0.5 * peak).flatten()
    t = float(theta[below[0]]) if len(below) and peak > 0 else float(theta[-1])
    alpha = min(max(math.sin(t) / math.sqrt(math.sqrt(2.0) - math.cos(t) ** 2), 1e-3), 1.0)
    rho_s, rho_d = 4.0 * math.pi * alpha**2 * peak, math.pi * floor
    p_spec = rho_s / (rho_s + rho_d) if rho_s + rho_d > 0 else 0.5
    return alpha, min(max(p_spec, 0.1), 0.9)
