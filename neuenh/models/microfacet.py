"""Microfacet pieces, written once: normal distributions D (GGX, Beckmann), Smith's G1 and the
V-groove G; the GGX and Cook-Torrance graphs and the alternative terms (``models.alternatives``)
use them.

    slope²(w)   = (w_x / a_x)² + (w_y / a_y)²                      anisotropic stretch of a direction
    D_GGX(h)    = 1 / (pi a_x a_y (slope²(h) + h_z²)²)              Walter et al. 2007 eq. 33; Heitz 2014 eq. 85
    D_Beck(h)   = exp(-slope²(h) / h_z²) / (pi a_x a_y h_z^4)       Walter et al. 2007 eq. 25; Heitz 2014 eq. 83
    G1_GGX(w)   = 2 w_z / (w_z + sqrt(w_z² + a_x² w_x² + a_y² w_y²))  Walter et al. 2007 eq. 34; Heitz 2014 eq. 86
    G_Smith     = G1(wi) G1(wo)                                     separable form, Walter et al. 2007 eq. 23
    G_V-groove  = min(1, 2 h_z wo_z / (wo·h), 2 h_z wi_z / (wi·h))  Cook & Torrance 1982 (Torrance & Sparrow 1967)

Citations: Walter, Marschner, Li, Torrance, "Microfacet Models for Refraction through Rough
Surfaces", EGSR 2007; Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based
BRDFs", JCGT 2014; Cook, Torrance, "A Reflectance Model for Computer Graphics", ACM TOG 1982;
Torrance, Sparrow, "Theory for Off-Specular Reflection from Roughened Surfaces", JOSA 1967.

Everything is in the local shading frame (``neuenh.shading``: ``h`` the half vector, ``cos_h`` its
z, ``cos_d = wi·h = wo·h``) and written in the backend-neutral ``neuenh.ops`` vocabulary, so it runs
in torch, numpy, the FLOP counter and the exporters. chi+(h·n) = 1 throughout: the half vector of
two directions above the shading horizon always has h_z > 0.
"""

from __future__ import annotations

import math

from ..shading import Shading


def slope_sq(w, ax, ay):
    """(w_x / a_x)² + (w_y / a_y)²: the anisotropic stretch shared by GGX, Beckmann and Ward lobes."""
    return (w.x / ax) ** 2 + (w.y / ay) ** 2


def ggx_d(s: Shading, ax, ay):
    """D_GGX(h) for roughnesses ``ax, ay`` (Walter et al. 2007 eq. 33, anisotropic: Heitz 2014 eq. 85)."""
    stretch = slope_sq(s.h, ax, ay) + s.cos_h**2  # h_z² (1 + tan²θh stretched): the ellipsoid's quadric
    return 1.0 / (math.pi * ax * ay * stretch**2)  # the normalisation pi a_x a_y, squared quadric


def beckmann_d(s: Shading, ax, ay):
    """D_Beckmann(h) (Walter et al. 2007 eq. 25, anisotropic: Heitz 2014 eq. 83), in log space so
    that tiny roughness at grazing h gives 0 with a finite gradient instead of 0 * inf."""
    exponent = -slope_sq(s.h, ax, ay) / s.cos_h**2  # -tan²θh, stretched per axis
    log_norm = s.xp.log(math.pi * ax * ay) + 4.0 * s.xp.log(s.cos_h)  # log of pi a_x a_y cos⁴θh
    return s.xp.exp(exponent - log_norm)


def ggx_distribution(s: Shading):
    """D = D_GGX(h) at the material's roughness (``alpha_x``, ``alpha_y``)."""
    return ggx_d(s, s.params["alpha_x"], s.params["alpha_y"])


def beckmann_distribution(s: Shading):
    """D = D_Beckmann(h) at the material's roughness (``alpha_x``, ``alpha_y``)."""
    return beckmann_d(s, s.params["alpha_x"], s.params["alpha_y"])


def ggx_smith_g1(s: Shading, w, cos_w):
    """G1(w) = 1 / (1 + Lambda(w)) of GGX (Walter et al. 2007 eq. 34; Heitz 2014 eq. 86), written
    without tan so it is exact and finite at grazing."""
    ax, ay = s.params["alpha_x"], s.params["alpha_y"]
    projected = (ax * w.x) ** 2 + (ay * w.y) ** 2  # the roughness ellipse seen from w: tan²θ stretched, times cos²θ
    return 2.0 * cos_w / (cos_w + s.xp.sqrt(cos_w**2 + projected))


def smith_shadowing(s: Shading):
    """G = G1(wi) G1(wo): the separable Smith masking-shadowing (Walter et al. 2007 eq. 23)."""
    return ggx_smith_g1(s, s.wi, s.cos_i) * ggx_smith_g1(s, s.wo, s.cos_o)  # shadowing of wi, masking of wo


def v_groove_shadowing(s: Shading):
    """G = min(1, masking, shadowing) of symmetric V-grooves (Cook & Torrance 1982, after Torrance &
    Sparrow 1967); wo·h = wi·h = cos_d."""
    masking = 2.0 * s.cos_h * s.cos_o / s.cos_d  # the groove's far wall hides wo
    shadowing = 2.0 * s.cos_h * s.cos_i / s.cos_d  # ... or keeps light from wi
    return s.xp.clamp(s.xp.minimum(masking, shadowing), hi=1.0)
