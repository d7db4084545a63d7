"""Normalised Blinn-Phong BRDF.

    f_r = M + S · D      graph: M + (S × D)

    M = rho_d / pi                       Lambertian diffuse
    S = rho_s                            specular albedo
    D = (e + 8) / (8 pi) (n·h)^e         Blinn's half-vector lobe, energy-normalised

Citations: Blinn, "Models of Light Reflection for Computer Synthesized Pictures", SIGGRAPH 1977;
the (e + 8) / (8 pi) normalisation from Akenine-Möller, Haines, Hoffman, "Real-Time Rendering"
(3rd ed., eq. 7.49). Isotropic: no tangent. 5 positions, 9 parameters.
"""

from __future__ import annotations

import math

from ..graph import Graph, Term, add, mul
from ..params import ParamSpec, ParamSpecs
from ..shading import Shading
from .common import NORMAL, RHO_D, RHO_S, lambertian, specular_albedo

SHININESS = ParamSpec("shininess", 1, 1.0, 1e4, scale="log", doc="Blinn-Phong exponent e")


def blinn_lobe(s: Shading):
    """D = (e + 8)/(8 pi) (n.h)^e, as exp(e log(n.h)) so large exponents keep finite gradients."""
    e = s.params["shininess"]
    return (e + 8.0) / (8.0 * math.pi) * s.xp.exp(e * s.xp.log(s.cos_h))


def build() -> tuple[Graph, ParamSpecs]:
    M = Term("M", 3, lambertian, reads_directions=False)  # Lambertian diffuse rho_d/pi
    S = Term("S", 3, specular_albedo, reads_directions=False)  # specular albedo rho_s
    D = Term("D", 1, blinn_lobe, reads_directions=True)  # normalised Blinn lobe
    return Graph(add(M, mul(S, D))), ParamSpecs((NORMAL, RHO_D, RHO_S, SHININESS))
