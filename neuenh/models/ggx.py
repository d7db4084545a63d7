"""Anisotropic GGX microfacet BRDF, as the paper's computational graph.

    f_r = M + S · D · F · G · (1/E)      graph: M + ((((S × D) × F) × G) × invE)

    M    = rho_d / pi                                          Lambertian diffuse
    S    = rho_s                                               specular albedo
    D    = 1 / (pi a_x a_y (h_x²/a_x² + h_y²/a_y² + h_z²)²)    GGX normal distribution
    F    = f0 + (1 - f0) (1 - wi·h)^5                          Schlick Fresnel
    G    = G1(wi) G1(wo),  G1(w) = 2 w_z / (w_z + sqrt(w_z² + a_x² w_x² + a_y² w_y²))
    invE = 1 / (4 cos_i cos_o)

Citations: Walter, Marschner, Li, Torrance, "Microfacet Models for Refraction through Rough
Surfaces", EGSR 2007 (D eq. 33, Smith G1 eq. 34, Jacobian eq. 20); the anisotropic forms of D and
G1 from Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 2014
(eqs. 85-86); Schlick, "An Inexpensive BRDF Model for Physically-based Rendering", 1994; the graph,
parameters and enhancement from Shen, Ma, Zhou, Wu, "Neural Enhancement of Analytical Appearance
Models" (Sec. 3). 11 positions, 12 parameters. D and G are ``models.microfacet``'s.

``build(alternatives=True)`` offers each of M, D, F and G's alternative analytical terms
(``models.alternatives``) as further digits; F is then an RGB position (Schlick broadcasts).
"""

from __future__ import annotations

from ..graph import Graph, Term, add, mul
from ..params import ParamSpecs
from .alternatives import microfacet_alternatives
from .common import MICROFACET_PARAMS, inverse_microfacet_normalisation, lambertian, schlick_fresnel, specular_albedo
from .microfacet import beckmann_distribution, ggx_distribution, smith_shadowing


def build(alternatives: bool = False) -> tuple[Graph, ParamSpecs]:
    alt = microfacet_alternatives(other_d=("beckmann", beckmann_distribution)) if alternatives else {}
    f_width = 3 if alternatives else 1  # the conductor Fresnel is RGB
    M = Term("M", 3, lambertian, False, "lambert", alternatives=alt.get("M", ()))  # Lambertian rho_d/pi
    S = Term("S", 3, specular_albedo, False, "albedo")  # specular albedo rho_s
    D = Term("D", 1, ggx_distribution, True, "ggx", alternatives=alt.get("D", ()))  # GGX distribution
    F = Term("F", f_width, schlick_fresnel, True, "schlick", alternatives=alt.get("F", ()))  # Schlick, f0
    G = Term("G", 1, smith_shadowing, True, "smith", alternatives=alt.get("G", ()))  # separable Smith G1 G1
    invE = Term("invE", 1, inverse_microfacet_normalisation, True, "jacobian")  # 1/(4 cos_i cos_o)
    return Graph(add(M, mul(S, D, F, G, invE))), ParamSpecs(MICROFACET_PARAMS)
