"""Independent float64 numpy re-derivations of every analytical model's f_r (no cosine factor).

Written from the papers in the *angular* forms, deliberately unlike the library's vector forms:

* shading frame: the normal from its two slope angles, the geometric x axis carried by the smallest
  rotation taking z to n (Rodrigues' rotation formula about z × n), then rotated by ``t_theta``
  about n (Rodrigues again); the bitangent is n × t;
* GGX D: Walter et al. 2007 eq. 33 with the anisotropic azimuthal roughness of Heitz 2014 eq. 85,
  in tan²θh, cos⁴θh and the half vector's azimuth φh:
  ``D = 1 / (π αx αy cos⁴θh (1 + tan²θh (cos²φh/αx² + sin²φh/αy²))²)``;
* GGX Smith G1 through Λ (Heitz 2014 eq. 86): ``Λ(ω) = (−1 + sqrt(1 + α(φ)² tan²θ)) / 2`` with
  ``α(φ)² = cos²φ αx² + sin²φ αy²``, ``G = G1(ωi) G1(ωo)`` (separable, Walter eq. 23);
* Beckmann D (Walter eq. 25, anisotropic Heitz eq. 83):
  ``exp(−tan²θh (cos²φh/αx² + sin²φh/αy²)) / (π αx αy cos⁴θh)``; V-groove G of Cook & Torrance 1982;
* Ward 1992 eq. 5a: ``ρs exp(−tan²θh (cos²φh/αx² + sin²φh/αy²)) / (4π αx αy sqrt(cosθi cosθo))``;
* normalised Blinn-Phong: ``ρs (e + 8)/(8π) cos^e θh``;
* Schlick 1994: ``F = f0 + (1 − f0)(1 − cos θd)^5``.

Every direction below the geometric or the shading horizon gives exactly zero. Nothing here imports
the library; inputs are numpy arrays broadcastable to ``(n, width)``.
"""

from __future__ import annotations

import math
from typing import Callable, Mapping

import numpy as np

Params = Mapping[str, np.ndarray]


# -- geometry ---------------------------------------------------------------------------------
def _rows(v: np.ndarray, n: int, width: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(v, dtype=np.float64).reshape(-1, width), (n, width))


def _rodrigues(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotate rows of v about unit rows of axis by angle (n,): v cos + (k × v) sin + k (k·v)(1 − cos)."""
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    kv = np.sum(axis * v, axis=1, keepdims=True)
    return v * c + np.cross(axis, v) * s + axis * kv * (1.0 - c)


def frame(params: Params, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(tangent, bitangent, normal) rows of the shading frame in the local frame."""
    slopes = _rows(params.get("normal", np.zeros(2)), n, 2)
    normal = np.stack([np.tan(slopes[:, 0]), np.tan(slopes[:, 1]), np.ones(n)], axis=1)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    z = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (n, 3))
    x = np.broadcast_to(np.array([1.0, 0.0, 0.0]), (n, 3))
    cross = np.cross(z, normal)
    sin_tilt = np.linalg.norm(cross, axis=1)
    tilted = sin_tilt > 0
    axis = np.where(tilted[:, None], cross / np.where(tilted, sin_tilt, 1.0)[:, None], z)
    tilt = np.arctan2(sin_tilt, normal[:, 2])
    tangent = _rodrigues(x, axis, tilt)
    t_theta = _rows(params.get("t_theta", np.zeros(1)), n, 1)[:, 0]
    tangent = _rodrigues(tangent, normal, t_theta)
    return tangent, np.cross(normal, tangent), normal


def _angles(w: np.ndarray, t: np.ndarray, b: np.ndarray, nrm: np.ndarray):
    """cos θ, tan² θ and azimuth φ of rows w in the frame (t, b, n)."""
    cos = np.sum(w * nrm, axis=1)
    sin2 = np.clip(1.0 - cos * cos, 0.0, None)
    phi = np.arctan2(np.sum(w * b, axis=1), np.sum(w * t, axis=1))
    return cos, sin2 / np.where(cos > 0, cos * cos, 1.0), phi


def _azimuthal_inverse_sq(phi, ax, ay):
    """cos²φ/αx² + sin²φ/αy²: the elliptical stretch of Ward, Beckmann and GGX lobes."""
    return np.cos(phi) ** 2 / ax**2 + np.sin(phi) ** 2 / ay**2


# -- terms ------------------------------------------------------------------------------------
def ggx_d(cos_h, tan2_h, phi_h, ax, ay):
    """Walter et al. 2007 eq. 33 (anisotropic: Heitz 2014 eq. 85)."""
    return 1.0 / (math.pi * ax * ay * cos_h**4 * (1.0 + tan2_h * _azimuthal_inverse_sq(phi_h, ax, ay)) ** 2)


def ggx_g1(tan2, phi, ax, ay):
    """Smith G1 = 1 / (1 + Λ), Λ from Heitz 2014 eq. 86."""
    alpha2 = np.cos(phi) ** 2 * ax**2 + np.sin(phi) ** 2 * ay**2
    lam = (-1.0 + np.sqrt(1.0 + alpha2 * tan2)) / 2.0
    return 1.0 / (1.0 + lam)


def beckmann_d(cos_h, tan2_h, phi_h, ax, ay):
    """Beckmann & Spizzichino 1963, Walter eq. 25 / Heitz eq. 83."""
    return np.exp(-tan2_h * _azimuthal_inverse_sq(phi_h, ax, ay)) / (math.pi * ax * ay * cos_h**4)


def v_groove_g(cos_h, cos_i, cos_o, cos_d):
    """Cook & Torrance 1982 (after Torrance & Sparrow 1967)."""
    return np.minimum(1.0, np.minimum(2.0 * cos_h * cos_o / cos_d, 2.0 * cos_h * cos_i / cos_d))


def schlick(f0, cos_d):
    return f0 + (1.0 - f0) * (1.0 - cos_d) ** 5


# -- models -----------------------------------------------------------------------------------
def _geometry(wi, wo, params):
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    n = wi.shape[0]
    t, b, nrm = frame(params, n)
    h = wi + wo
    length = np.linalg.norm(h, axis=1, keepdims=True)
    h = h / np.where(length > 0, length, 1.0)
    cos_i, tan2_i, phi_i = _angles(wi, t, b, nrm)
    cos_o, tan2_o, phi_o = _angles(wo, t, b, nrm)
    cos_h, tan2_h, phi_h = _angles(h, t, b, nrm)
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0) & (cos_i > 0) & (cos_o > 0)
    g = dict(cos_i=cos_i, tan2_i=tan2_i, phi_i=phi_i, cos_o=cos_o, tan2_o=tan2_o, phi_o=phi_o,
             cos_h=cos_h, tan2_h=tan2_h, phi_h=phi_h, cos_d=np.clip(np.sum(wi * h, axis=1), 0.0, 1.0),
             above=above)
    return n, g


def _scalar(params, name, n):
    return _rows(params[name], n, 1)[:, 0]


def _ggx_spec(g, p, n):
    ax, ay, f0 = _scalar(p, "alpha_x", n), _scalar(p, "alpha_y", n), _scalar(p, "f0", n)
    d = ggx_d(g["cos_h"], g["tan2_h"], g["phi_h"], ax, ay)
    gg = ggx_g1(g["tan2_i"], g["phi_i"], ax, ay) * ggx_g1(g["tan2_o"], g["phi_o"], ax, ay)
    return d * gg * schlick(f0, g["cos_d"]) / (4.0 * g["cos_i"] * g["cos_o"])


def _cook_torrance_spec(g, p, n):
    ax, ay, f0 = _scalar(p, "alpha_x", n), _scalar(p, "alpha_y", n), _scalar(p, "f0", n)
    d = beckmann_d(g["cos_h"], g["tan2_h"], g["phi_h"], ax, ay)
    gg = v_groove_g(g["cos_h"], g["cos_i"], g["cos_o"], g["cos_d"])
    return d * gg * schlick(f0, g["cos_d"]) / (4.0 * g["cos_i"] * g["cos_o"])


def _ward_spec(g, p, n):
    ax, ay = _scalar(p, "alpha_x", n), _scalar(p, "alpha_y", n)
    lobe = np.exp(-g["tan2_h"] * _azimuthal_inverse_sq(g["phi_h"], ax, ay))
    return lobe / (4.0 * math.pi * ax * ay * np.sqrt(g["cos_i"] * g["cos_o"]))


def _blinn_phong_spec(g, p, n):
    e = _scalar(p, "shininess", n)
    return (e + 8.0) / (8.0 * math.pi) * np.clip(g["cos_h"], 0.0, None) ** e


SPECULAR: dict[str, Callable] = {
    "ggx": _ggx_spec,
    "cook_torrance": _cook_torrance_spec,
    "ward": _ward_spec,
    "blinn_phong": _blinn_phong_spec,
    "ggx_residual": _ggx_spec,  # its residual R is zero in the analytical model
}


def f_r(model: str, wi: np.ndarray, wo: np.ndarray, params: Params) -> np.ndarray:
    """f_r (n, 3) of ``model`` = ρd/π + ρs · specular lobe, zero below either horizon."""
    n, g = _geometry(wi, wo, params)
    above = g["above"]
    with np.errstate(all="ignore"):  # rows below a horizon may divide by zero; they are masked
        spec = SPECULAR[model](g, params, n)
        out = _rows(params["rho_d"], n, 3) / math.pi + _rows(params["rho_s"], n, 3) * spec[:, None]
    return np.where(above[:, None], out, 0.0)


# -- alternative terms (neuenh.models.alternatives), from their papers' own forms ---------------
def gtr_d(cos_h, a2, gamma):
    """Burley 2012, GTR: c / (a² cos²θh + sin²θh)^γ, c = (γ−1)(a²−1) / (π (1 − (a²)^(1−γ)))."""
    c = (gamma - 1.0) * (a2 - 1.0) / (math.pi * (1.0 - a2 ** (1.0 - gamma)))
    return c / (a2 * cos_h**2 + (1.0 - cos_h**2)) ** gamma


def student_t_d(cos_h, tan2_h, phi_h, ax, ay, gamma):
    """Ribardière et al. 2017 eq. 5: (γ−1)^γ / (π αx αy cos⁴θh ((γ−1) + tan²θh (cos²φ/αx² + sin²φ/αy²))^γ)."""
    stretch = tan2_h * _azimuthal_inverse_sq(phi_h, ax, ay)
    return (gamma - 1.0) ** gamma / (math.pi * ax * ay * cos_h**4 * ((gamma - 1.0) + stretch) ** gamma)


def hazy_d(cos_h, tan2_h, phi_h, ax, ay, weight, extent):
    """Barla et al. 2018: (1 − χ) GGX(α) + χ GGX(min(λ α, 1))."""
    haze = ggx_d(cos_h, tan2_h, phi_h, np.minimum(extent * ax, 1.0), np.minimum(extent * ay, 1.0))
    return (1.0 - weight) * ggx_d(cos_h, tan2_h, phi_h, ax, ay) + weight * haze


def conductor_f(cos_d, eta, kappa):
    """Fresnel's equations with a complex index n = η + iκ in complex arithmetic (Born & Wolf):
    cos θt = sqrt(1 − sin²θ / n²), rs = (cos − n cos θt) / (cos + n cos θt), rp = (n cos − cos θt) /
    (n cos + cos θt), F = (|rs|² + |rp|²) / 2. (n, 3) from cos_d (n,) and eta, kappa (n, 3)."""
    n_c = eta + 1j * kappa
    c = cos_d[:, None].astype(np.complex128)
    cos_t = np.sqrt(1.0 - (1.0 - c**2) / n_c**2)
    rs = (c - n_c * cos_t) / (c + n_c * cos_t)
    rp = (n_c * c - cos_t) / (n_c * c + cos_t)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def schlick_tint_f(cos_d, f0, tint):
    """Hoffman 2019: Schlick minus a cosθ (1 − cosθ)^6, a = (1 − tint) Schlick(θ̄) / (cos θ̄ (1 − cos θ̄)^6)
    at cos θ̄ = 1/7; clipped at 0. (n, 3) from cos_d, f0 (n,) and tint (n, 3)."""
    bar = 1.0 / 7.0
    peak = bar * (1.0 - bar) ** 6
    a = (1.0 - tint) * schlick(f0, bar)[:, None] / peak
    return np.clip(schlick(f0, cos_d)[:, None] - a * (cos_d * (1.0 - cos_d) ** 6)[:, None], 0.0, None)


def height_correlated_g(tan2_i, phi_i, tan2_o, phi_o, ax, ay):
    """Heitz 2014 eq. 99: 1 / (1 + Λ(ωi) + Λ(ωo)), Λ from eq. 86."""
    def lam(tan2, phi):
        return (-1.0 + np.sqrt(1.0 + (np.cos(phi) ** 2 * ax**2 + np.sin(phi) ** 2 * ay**2) * tan2)) / 2.0
    return 1.0 / (1.0 + lam(tan2_i, phi_i) + lam(tan2_o, phi_o))


def oren_nayar_factor(cos_i, phi_i, cos_o, phi_o, sigma):
    """Oren & Nayar 1994 eq. 30: A + B max(0, cos(φi − φo)) sin α tan β, α = max(θi, θo), β = min."""
    theta_i, theta_o = np.arccos(np.clip(cos_i, -1, 1)), np.arccos(np.clip(cos_o, -1, 1))
    alpha, beta = np.maximum(theta_i, theta_o), np.minimum(theta_i, theta_o)
    s2 = sigma**2
    a, b = 1.0 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)
    return a + b * np.maximum(0.0, np.cos(phi_i - phi_o)) * np.sin(alpha) * np.tan(beta)


def ggx_with(wi, wo, params: Params, *, m="lambert", d="ggx", f="schlick", g="smith") -> np.ndarray:
    """GGX's f_r (n, 3) with the named alternatives at M, D, F and G (``neuenh.models.alternatives``'
    choice names), zero below either horizon."""
    n, geo = _geometry(wi, wo, params)
    ax, ay, f0 = _scalar(params, "alpha_x", n), _scalar(params, "alpha_y", n), _scalar(params, "f0", n)
    angles = geo["cos_h"], geo["tan2_h"], geo["phi_h"]
    with np.errstate(all="ignore"):
        dist = {"ggx": lambda: ggx_d(*angles, ax, ay),
                "beckmann": lambda: beckmann_d(*angles, ax, ay),
                "gtr": lambda: gtr_d(geo["cos_h"], np.minimum(ax * ay, 0.999), _scalar(params, "gtr_gamma", n)),
                "student_t": lambda: student_t_d(*angles, ax, ay, _scalar(params, "std_gamma", n)),
                "hazy_ggx": lambda: hazy_d(*angles, ax, ay, _scalar(params, "haze_weight", n),
                                           _scalar(params, "haze_extent", n))}[d]()
        fresnel = {"schlick": lambda: schlick(f0, geo["cos_d"])[:, None],
                   "conductor": lambda: conductor_f(geo["cos_d"], _rows(params["eta"], n, 3), _rows(params["kappa"], n, 3)),
                   "schlick_tint": lambda: schlick_tint_f(geo["cos_d"], f0, _rows(params["edge_tint"], n, 3))}[f]()
        shadow = {"smith": lambda: ggx_g1(geo["tan2_i"], geo["phi_i"], ax, ay) * ggx_g1(geo["tan2_o"], geo["phi_o"], ax, ay),
                  "height_correlated": lambda: height_correlated_g(geo["tan2_i"], geo["phi_i"], geo["tan2_o"],
                                                                  geo["phi_o"], ax, ay)}[g]()
        diffuse = _rows(params["rho_d"], n, 3) / math.pi
        if m == "oren_nayar":
            diffuse = diffuse * oren_nayar_factor(geo["cos_i"], geo["phi_i"], geo["cos_o"], geo["phi_o"],
                                                  _scalar(params, "on_sigma", n))[:, None]
        spec = (dist * shadow / (4.0 * geo["cos_i"] * geo["cos_o"]))[:, None] * fresnel
        out = diffuse + _rows(params["rho_s"], n, 3) * spec
    return np.where(geo["above"][:, None], out, 0.0)
