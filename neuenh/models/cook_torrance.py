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
offers the microfacet alternatives (``models.alternatives``; GGX in place of Beckmann at D). D and
G are ``models.microfacet``'s.
"""

from __future__ import annotations

from ..graph import Graph, Term, add, mul
from ..params import ParamSpecs
from .alternatives import microfacet_alternatives
from .common import MICROFACET_PARAMS, inverse_microfacet_normalisation, lambertian, schlick_fresnel, specular_albedo
from .microfacet import beckmann_distribution, ggx_distribution, v_groove_shadowing


def build(alternatives: bool = False) -> tuple[Graph, ParamSpecs]:
    alt = microfacet_alternatives(other_d=("ggx", ggx_distribution)) if alternatives else {}
    f_width = 3 if alternatives else 1  # the conductor Fresnel is RGB
    M = Term("M", 3, lambertian, False, "lambert", alternatives=alt.get("M", ()))  # Lambertian rho_d/pi
    S = Term("S", 3, specular_albedo, False, "albedo")  # specular albedo rho_s
    D = Term("D", 1, beckmann_distribution, True, "beckmann", alternatives=alt.get("D", ()))  # Beckmann
    F = Term("F", f_width, schlick_fresnel, True, "schlick", alternatives=alt.get("F", ()))  # Schlick, f0
    G = Term("G", 1, v_groove_shadowing, True, "v_groove", alternatives=alt.get("G", ()))  # V-groove
    invE = Term("invE", 1, inverse_microfacet_normalisation, True, "jacobian")  # 1/(4 cos_i cos_o)
    return Graph(add(M, mul(S, D, F, G, invE))), ParamSpecs(MICROFACET_PARAMS)
