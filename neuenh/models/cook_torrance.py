"""Cook-Torrance microfacet BRDF with an anisotropic Beckmann distribution.

    f_r = M + S · D · F · G · (1/E)      graph: M + ((((S × D) × F) × G) × invE)

    M    = rho_d / pi                                            Lambertian diffuse
    S    = rho_s                                                 specular albedo
    D    = exp(-(h_x²/a_x² + h_y²/a_y²) / h_z²) / (pi a_x a_y h_z^4)   Beckmann distribution
    F    = f0 + (1 - f0) (1 - wi·h)^5                            Schlick Fresnel
    G    = min(1, 2 h_z wo_z / (wo·h), 2 h_z wi_z / (wo·h))      V-groove masking-shadowing
    invE = 1 / (4 cos_i cos_o)

Citations: Cook, Torrance, "A Reflectance Model for Computer Graphics", ACM TOG 1982 (the model and
its V-groove G from Torrance & Sparrow 1967); Beckmann & Spizzichino 1963, normalised and
anisotropic as in Walter et al. 2007 (eq. 25) and Heitz 2014 (eq. 83); Schlick 1994. The 1/(4 cos cos)
normalisation replaces the original 1/(pi cos cos) so that D is a normalised distribution, as in
the paper's enhanced Cook-Torrance (Fig. 14). 11 positions, 12 parameters. ``build(alternatives=True)``
offers the microfacet alternatives (``models.alternatives``; GGX in place of Beckmann at D).
"""

from __future__ import annotations

import math

from ..graph import Graph, Term, add, mul
from ..params import ParamSpecs
from ..shading import Shading
from .alternatives import microfacet_alternatives
from .common import (
    MICROFACET_PARAMS,
    anisotropic_slope_sq,
    inverse_microfacet_normalisation,
    lambertian,
    schlick_fresnel,
    specular_albedo,
)


def beckmann_distribution(s: Shading):
    """D(h), evaluated in log space so that tiny roughness at grazing h gives 0 with a finite
    gradient instead of 0 * inf."""
    ax, ay = s.params["alpha_x"], s.params["alpha_y"]
    exponent = -anisotropic_slope_sq(s, s.h) / s.cos_h**2
    log_norm = s.xp.log(math.pi * ax * ay) + 4.0 * s.xp.log(s.cos_h)
    return s.xp.exp(exponent - log_norm)


def v_groove_shadowing(s: Shading):
    """G: Cook & Torrance 1982 eq. (after Torrance & Sparrow 1967); wo.h = wi.h = cos_d."""
    masking = 2.0 * s.cos_h * s.cos_o / s.cos_d
    shadowing = 2.0 * s.cos_h * s.cos_i / s.cos_d
    return s.xp.clamp(s.xp.minimum(masking, shadowing), hi=1.0)


def build(alternatives: bool = False) -> tuple[Graph, ParamSpecs]:
    from .ggx import ggx_distribution  # ggx imports this module's Beckmann

    alt = microfacet_alternatives(other_d=("ggx", ggx_distribution)) if alternatives else {}
    f_width = 3 if alternatives else 1  # the conductor Fresnel is RGB
    M = Term("M", 3, lambertian, False, "lambert", alternatives=alt.get("M", ()))  # Lambertian rho_d/pi
    S = Term("S", 3, specular_albedo, False, "albedo")  # specular albedo rho_s
    D = Term("D", 1, beckmann_distribution, True, "beckmann", alternatives=alt.get("D", ()))  # Beckmann
    F = Term("F", f_width, schlick_fresnel, True, "schlick", alternatives=alt.get("F", ()))  # Schlick, f0
    G = Term("G", 1, v_groove_shadowing, True, "v_groove", alternatives=alt.get("G", ()))  # V-groove
    invE = Term("invE", 1, inverse_microfacet_normalisation, True, "jacobian")  # 1/(4 cos_i cos_o)
    return Graph(add(M, mul(S, D, F, G, invE))), ParamSpecs(MICROFACET_PARAMS)
