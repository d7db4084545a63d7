"""Alternative analytical terms: what a digit may choose at a node besides the original term and
its neural modules (the paper's m-ary extension, Sec. 4.1, which it leaves to future work).

Each alternative is a ``graph.Term`` with the position's name, its own formula (written in the
backend-neutral ``neuenh.ops`` vocabulary, so it runs in torch, numpy, the counting backend and the
exporters), a ``choice`` name, and the extra per-material parameters it reads (ranges, constrained
mapping and initial value as every parameter: ``params.ParamSpec``). Formulas and citations:

D, normal distributions (width 1; every one integrates to 1 over projected area, tests):
* ``beckmann`` (for GGX; Cook-Torrance gets ``ggx`` here): anisotropic Beckmann (Walter et al. 2007 eq. 25; Heitz 2014 eq. 83), as in
  Cook-Torrance (``models.microfacet.beckmann_distribution``).
* ``gtr``: Burley's generalized Trowbridge-Reitz (Burley, "Physically-Based Shading at Disney",
  SIGGRAPH 2012 course, eq. 4 and its normalisation in the addenda)
  ``D = c / (a² cos²θh + sin²θh)^γ``, ``c = (γ−1)(1−a²) / (π ((a²)^(1−γ) − 1))``. Burley's GTR is
  isotropic: it reads ``a² = αx αy`` (the geometric mean of the two roughnesses), clamped to at most
  ``GTR_A2_MAX`` where ``c`` becomes 0/0; ``γ = 2`` is isotropic GGX, γ → 1 Berry's distribution.
* ``student_t``: the Student's t-distribution of slopes (Ribardière, Bringier, Meneveaux, Simonot,
  "STD: Student's t-Distribution of Slopes for Microfacet Based BSDFs", Eurographics 2017, eq. 5)
  ``D = (1 + r² / (γ−1))^(−γ) / (π αx αy cos⁴θh)``, ``r² = (hx²/αx² + hy²/αy²) / hz²``:
  GGX at γ = 2, Beckmann as γ → ∞; anisotropic.
* ``hazy_ggx``: a two-lobe GGX mixture for hazy gloss (Barla, Pacanowski, Vangorp, "A Composite
  BRDF Model for Hazy Gloss", EGSR 2018): ``(1 − χ) D_GGX(αx, αy) + χ D_GGX(λαx, λαy)``, the haze
  lobe's roughness clamped at 1; a mixture of normalised lobes is normalised.

F, Fresnel (width 3: the F position is RGB when alternatives are on; Schlick's scalar broadcasts):
* ``conductor``: the exact unpolarised Fresnel reflectance of a conductor with complex index
  ``η + iκ`` per channel (Born & Wolf; PBRT 3rd ed. eq. 8.3), at ``cos θd = wi·h``.
* ``schlick_tint``: Schlick with an edge tint, Hoffman's "F82" form (Hoffman, "Fresnel Equations
  Considered Harmful", EGSR 2019 talk / Adobe Standard Material): ``F = Schlick(f0, θ) −
  a cosθ (1 − cosθ)^6`` with ``a`` chosen so that ``F(θ̄) = tint · Schlick(f0, θ̄)`` at
  ``cos θ̄ = 1/7``, where the correction peaks; tint 1 is Schlick.

G, masking-shadowing (width 1):
* ``height_correlated``: the height-correlated Smith function (Heitz 2014 eq. 99)
  ``G2 = 1 / (1 + Λ(wi) + Λ(wo))``, written ``2 ci co / (co Ri + ci Ro)`` with
  ``R = sqrt(c² + αx² wx² + αy² wy²)`` so it is finite at grazing.

M, diffuse (width 3):
* ``oren_nayar``: Oren & Nayar's qualitative rough-diffuse model (Oren & Nayar, "Generalization of
  Lambert's Reflectance Model", SIGGRAPH 1994, eq. 30) ``ρd/π (A + B max(0, cos(φi−φo)) sinα tanβ)``,
  ``A = 1 − σ²/(2(σ² + 0.33))``, ``B = 0.45 σ²/(σ² + 0.09)``; with ``sinα tanβ cos(φi−φo) =
  (wi·wo)_xy / max(cos θi, cos θo)`` it needs no angle and stays finite everywhere.
"""

from __future__ import annotations

import math

from ..graph import Term
from ..params import ParamSpec
from ..shading import COS_EPS, Shading
from .microfacet import ggx_d, slope_sq

# -- extra per-material parameters (their names are unique across a model's parameters) ----------
# Each starts where its term equals or nears the original (GGX, Schlick, Lambert), so a candidate
# that switches to it begins close to its parent.
GTR_GAMMA = ParamSpec("gtr_gamma", 1, 1.05, 4.0, start=2.0, doc="GTR tail exponent γ (2: GGX)")
STD_GAMMA = ParamSpec("std_gamma", 1, 1.5, 40.0, scale="log", start=2.0,
                      doc="Student-t tail exponent γ (2: GGX; larger: towards Beckmann)")
HAZE_WEIGHT = ParamSpec("haze_weight", 1, 0.0, 1.0, start=0.1, doc="share χ of the haze lobe")
HAZE_EXTENT = ParamSpec("haze_extent", 1, 1.0, 10.0, start=3.0, doc="haze lobe roughness / core roughness λ")
ETA = ParamSpec("eta", 3, 0.05, 4.0, start=1.5, doc="conductor refractive index η (RGB)")
KAPPA = ParamSpec("kappa", 3, 0.0, 8.0, start=1.0, doc="conductor extinction coefficient κ (RGB)")
EDGE_TINT = ParamSpec("edge_tint", 3, 0.0, 2.0, start=1.0,
                      doc="reflectance near grazing / Schlick's there (RGB; 1: Schlick)")
ON_SIGMA = ParamSpec("on_sigma", 1, 0.0, 1.0, start=0.2, doc="Oren-Nayar facet slope deviation σ (rad)")

GTR_A2_MAX = 0.999  # GTR's normalisation is 0/0 at a² = 1 (its limit there is 1/π)


# -- D ----------------------------------------------------------------------------------------------
def gtr_distribution(s: Shading):
    """Burley's GTR, isotropic in a² = αx αy, in log space so that tiny roughness stays finite."""
    xp, gamma = s.xp, s.params["gtr_gamma"]
    a2 = xp.clamp(s.params["alpha_x"] * s.params["alpha_y"], hi=GTR_A2_MAX)
    # c = (γ−1)(1−a²) / (π ((a²)^(1−γ) − 1)); (a²)^(1−γ) = exp((1−γ) ln a²) > 1 for a² < 1, γ > 1
    log_c = (xp.log(gamma - 1.0) + xp.log(1.0 - a2) - math.log(math.pi)
             - xp.log(xp.exp((1.0 - gamma) * xp.log(a2)) - 1.0))
    cos2 = s.cos_h**2
    base = a2 * cos2 + (1.0 - cos2)  # a² cos²θh + sin²θh, at least a² > 0
    return xp.exp(log_c - gamma * xp.log(base))


def student_t_distribution(s: Shading):
    """The STD of Ribardière et al. 2017, in log space (tiny roughness at grazing h gives 0 with
    a finite gradient)."""
    xp, gamma = s.xp, s.params["std_gamma"]
    ax, ay = s.params["alpha_x"], s.params["alpha_y"]
    r2 = slope_sq(s.h, ax, ay) / s.cos_h**2
    log_norm = xp.log(math.pi * ax * ay) + 4.0 * xp.log(s.cos_h)
    return xp.exp(-gamma * xp.log(1.0 + r2 / (gamma - 1.0)) - log_norm)


def hazy_ggx_distribution(s: Shading):
    """(1 − χ) GGX(α) + χ GGX(min(λα, 1)): a sharp core under a wide haze lobe."""
    xp, chi, extent = s.xp, s.params["haze_weight"], s.params["haze_extent"]
    ax, ay = s.params["alpha_x"], s.params["alpha_y"]
    core = ggx_d(s, ax, ay)
    haze = ggx_d(s, xp.clamp(extent * ax, hi=1.0), xp.clamp(extent * ay, hi=1.0))
    return (1.0 - chi) * core + chi * haze


# -- F ----------------------------------------------------------------------------------------------
def conductor_fresnel(xp, cos, eta, kappa):
    """Unpolarised Fresnel reflectance of a conductor with complex index ``eta + i kappa`` at the
    incidence cosine ``cos`` (in [COS_EPS, 1]); broadcasts per channel."""
    cos2 = cos * cos
    sin2 = 1.0 - cos2
    t0 = eta * eta - kappa * kappa - sin2
    eta_kappa2 = eta * eta * kappa * kappa
    # a² + b², kept at least 1e-12 (= a's floor below): its square root has a finite gradient at the
    # critical angle of a dielectric (t0 = 0 = κ), and t1 ≥ t2, t3 ≥ t4 below hold with a floored, so
    # F stays in [0, 1] (index-matched, η = 1 and κ = 0, at grazing it was -1/3)
    a2b2 = xp.sqrt(xp.clamp(t0 * t0 + 4.0 * eta_kappa2, 1e-24))
    # a² = (a² + b² + t0) / 2, written without its cancellation when t0 < 0 (κ ≪ η past the critical
    # angle, where F lost up to 6e-4 relative in float32): (a2b2 + t0) / 2 = max(t0, 0) +
    # 2η²κ² / (a2b2 + |t0|), both terms ≥ 0 (multiply a2b2 − |t0| by a2b2 + |t0|)
    a_squared = xp.clamp(t0, 0.0) + 2.0 * eta_kappa2 / (a2b2 + xp.abs(t0))
    # a kept off 0 so its gradient stays finite (a dielectric past its critical angle, which η < 1
    # with κ = 0 allows): where a² < 1e-12, F is off by up to ~4e-6 relative (rs moves by 4·a·cos/t1)
    a = xp.sqrt(xp.clamp(a_squared, 1e-12))
    t1 = a2b2 + cos2
    t2 = 2.0 * cos * a
    rs = (t1 - t2) / (t1 + t2)  # s-polarised
    t3 = cos2 * a2b2 + sin2 * sin2
    t4 = t2 * sin2
    rp = rs * (t3 - t4) / (t3 + t4)  # p-polarised
    return 0.5 * (rs + rp)


def conductor(s: Shading):
    """F = the conductor's Fresnel reflectance at wi·h, per channel."""
    return conductor_fresnel(s.xp, s.cos_d, s.params["eta"], s.params["kappa"])


_COS_BAR = 1.0 / 7.0  # where cosθ (1 − cosθ)^6 peaks (Hoffman 2019)


def schlick_tint(s: Shading):
    """Schlick minus Hoffman's edge correction a cosθ (1 − cosθ)^6, per channel."""
    xp, f0, tint, c = s.xp, s.params["f0"], s.params["edge_tint"], s.cos_d
    schlick = f0 + (1.0 - f0) * (1.0 - c) ** 5
    schlick_bar = f0 + (1.0 - f0) * (1.0 - _COS_BAR) ** 5  # Schlick at cos θ̄ = 1/7
    a = schlick_bar * (1.0 - tint) / (_COS_BAR * (1.0 - _COS_BAR) ** 6)
    return xp.clamp(schlick - a * c * (1.0 - c) ** 6, 0.0)


# -- G ----------------------------------------------------------------------------------------------
def height_correlated_smith(s: Shading):
    """G2 = 1 / (1 + Λ(wi) + Λ(wo)) = 2 ci co / (co Ri + ci Ro)."""
    xp, ax, ay = s.xp, s.params["alpha_x"], s.params["alpha_y"]
    ci, co = s.cos_i, s.cos_o
    r_i = xp.sqrt(ci**2 + (ax * s.wi.x) ** 2 + (ay * s.wi.y) ** 2)
    r_o = xp.sqrt(co**2 + (ax * s.wo.x) ** 2 + (ay * s.wo.y) ** 2)
    return 2.0 * ci * co / (co * r_i + ci * r_o)


# -- M ----------------------------------------------------------------------------------------------
def oren_nayar(s: Shading):
    """ρd/π (A + B max(0, (wi·wo)_xy) / max(cos θi, cos θo)), in the shading frame."""
    xp, sigma2 = s.xp, s.params["on_sigma"] ** 2
    a = 1.0 - 0.5 * sigma2 / (sigma2 + 0.33)
    b = 0.45 * sigma2 / (sigma2 + 0.09)
    azimuthal = xp.clamp(s.wi.x * s.wo.x + s.wi.y * s.wo.y, 0.0)  # cos(φi−φo) sinθi sinθo
    return s.params["rho_d"] / math.pi * (a + b * azimuthal / xp.maximum(s.cos_i, s.cos_o))


def _alternative(position: str, width: int, choice: str, formula, params=()) -> Term:
    return Term(position, width, formula, reads_directions=True, choice=choice, params=tuple(params))


def microfacet_alternatives(other_d: tuple[str, object]) -> dict[str, tuple[Term, ...]]:
    """The alternatives of a microfacet model's M, D, F and G positions, by position name.
    ``other_d``: (choice, formula) of the classic distribution the model does not use itself
    (Beckmann for GGX, GGX for Cook-Torrance), offered first."""
    return {
        "M": (_alternative("M", 3, "oren_nayar", oren_nayar, [ON_SIGMA]),),
        "D": (_alternative("D", 1, *other_d),
              _alternative("D", 1, "gtr", gtr_distribution, [GTR_GAMMA]),
              _alternative("D", 1, "student_t", student_t_distribution, [STD_GAMMA]),
              _alternative("D", 1, "hazy_ggx", hazy_ggx_distribution, [HAZE_WEIGHT, HAZE_EXTENT])),
        "F": (_alternative("F", 3, "conductor", conductor, [ETA, KAPPA]),
              _alternative("F", 3, "schlick_tint", schlick_tint, [EDGE_TINT])),
        "G": (_alternative("G", 1, "height_correlated", height_correlated_smith),),
    }


__all__ = ["COS_EPS", "conductor_fresnel", "microfacet_alternatives"]
