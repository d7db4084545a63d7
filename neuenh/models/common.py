"""Pieces shared by several analytical models: their parameter specs and common terms.

Valid ranges: the paper takes them from OpenSVBRDF statistics (Ma et al. 2023), which it does not
list; these are the physically meaningful ranges, wide enough for the stability grid
(roughness down to 1e-4). Roughness is mapped on a log axis so optimisers and neural modules
resolve near-mirror materials as well as rough ones.
"""

from __future__ import annotations

import math

from ..params import ParamSpec
from ..shading import Shading

NORMAL = ParamSpec(
    "normal", 2, -math.pi / 3, math.pi / 3,
    doc="shading-normal tilt: slope angles along x and y, n ∝ (tan a, tan b, 1)",
)
T_THETA = ParamSpec("t_theta", 1, -math.pi / 2, math.pi / 2, doc="tangent rotation about n (rad)")
RHO_D = ParamSpec("rho_d", 3, 0.0, 1.0, doc="diffuse albedo (RGB)")
RHO_S = ParamSpec("rho_s", 3, 0.0, 1.0, doc="specular albedo (RGB)")
ALPHA_X = ParamSpec("alpha_x", 1, 1e-4, 1.0, scale="log", doc="roughness along the tangent")
ALPHA_Y = ParamSpec("alpha_y", 1, 1e-4, 1.0, scale="log", doc="roughness along the bitangent")
F0 = ParamSpec("f0", 1, 0.0, 1.0, doc="Fresnel reflectance at normal incidence")

# The 12 analytical parameters of the paper's GGX, in its order (Sec. 3).
MICROFACET_PARAMS = (NORMAL, T_THETA, RHO_D, RHO_S, ALPHA_X, ALPHA_Y, F0)


def lambertian(s: Shading):
    """M = rho_d / pi (Lambert 1760)."""
    return s.params["rho_d"] / math.pi


def specular_albedo(s: Shading):
    """S = rho_s."""
    return s.params["rho_s"]


def schlick_fresnel(s: Shading):
    """F = f0 + (1 - f0) (1 - wi.h)^5 (Schlick 1994, eq. 15)."""
    f0 = s.params["f0"]
    return f0 + (1.0 - f0) * (1.0 - s.cos_d) ** 5


def inverse_microfacet_normalisation(s: Shading):
    """1/E = 1 / (4 cos_i cos_o), the microfacet Jacobian (Walter et al. 2007, eq. 20)."""
    return 1.0 / (4.0 * s.cos_i * s.cos_o)
