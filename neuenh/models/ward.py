"""Anisotropic Ward BRDF.

    f_r = M + S · D · (1/E)      graph: M + ((S × D) × invE)

    M    = rho_d / pi                                       Lambertian diffuse
    S    = rho_s                                            specular albedo
    D    = exp(-(h_x²/a_x² + h_y²/a_y²) / h_z²) / (pi a_x a_y)   elliptical Gaussian lobe
    invE = 1 / (4 sqrt(cos_i cos_o))                        Ward's normalisation

Citation: Ward, "Measuring and Modeling Anisotropic Reflection", SIGGRAPH 1992, eq. 5a
(exp(-tan² θh (cos² φh / a_x² + sin² φh / a_y²)) with tan² θh cos² φh = h_x² / h_z²).
No Fresnel term. 7 positions, 11 parameters.
"""

from __future__ import annotations

import math

from ..graph import Graph, Term, add, mul
from ..params import ParamSpecs
from ..shading import Shading
from .common import ALPHA_X, ALPHA_Y, NORMAL, RHO_D, RHO_S, T_THETA, lambertian, specular_albedo
from .microfacet import slope_sq


def ward_lobe(s: Shading):
    """D: the elliptical Gaussian in the half-vector slopes, normalised by pi a_x a_y."""
    ax, ay = s.params["alpha_x"], s.params["alpha_y"]
    return s.xp.exp(-slope_sq(s.h, ax, ay) / s.cos_h**2) / (math.pi * ax * ay)


def ward_normalisation(s: Shading):
    """1/E = 1 / (4 sqrt(cos_i cos_o))."""
    return 1.0 / (4.0 * s.xp.sqrt(s.cos_i * s.cos_o))


def build() -> tuple[Graph, ParamSpecs]:
    M = Term("M", 3, lambertian, reads_directions=False)  # Lambertian diffuse rho_d/pi
    S = Term("S", 3, specular_albedo, reads_directions=False)  # specular albedo rho_s
    D = Term("D", 1, ward_lobe, reads_directions=True)  # elliptical Gaussian lobe
    invE = Term("invE", 1, ward_normalisation, reads_directions=True)  # 1/(4 sqrt(cos cos))
    specs = ParamSpecs((NORMAL, T_THETA, RHO_D, RHO_S, ALPHA_X, ALPHA_Y))
    return Graph(add(M, mul(S, D, invE))), specs
