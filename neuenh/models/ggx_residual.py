"""Anisotropic GGX with a residual term: the paper's "residual network" baseline as a graph.

    f_r = (M + S · D · F · G · (1/E)) + R        graph: (M + ((((S × D) × F) × G) × invE)) + R

    M, S, D, F, G, invE   exactly as in ``neuenh.models.ggx``
    R    = 0                                     residual, zero in the analytical model

In the all-zero state this *is* GGX. Replacing only ``R`` by a neural module (state
``0000001000000``) appends an MLP to GGX's output that reads the direction pair, the 12 analytical
and the latent parameters — the residual baselines of Shen et al., "Neural Enhancement of
Analytical Appearance Models", Sec. 6 ("Residual Networks", hidden widths {32, 64, 64, 16} and
{32, 64, 128, 128, 64}), trained jointly with the per-material parameters like any enhancement.
The search is not meant to run on this model; it exists so the baselines reuse training, fitting,
bundles and rendering unchanged. 13 positions, 12 parameters.
"""

from __future__ import annotations

from ..graph import Graph, Term, add
from ..params import ParamSpecs
from ..shading import Shading
from . import ggx
from .common import MICROFACET_PARAMS

RESIDUAL_STATE = "0000001000000"  # only R neural


def zero_residual(s: Shading):
    """R = 0: the analytical model has no residual."""
    return 0.0 * s.cos_i


def build() -> tuple[Graph, ParamSpecs]:
    plain = ggx.build()[0].root
    R = Term("R", 3, zero_residual, reads_directions=True)  # residual, zero until made neural
    return Graph(add(plain, R)), ParamSpecs(MICROFACET_PARAMS)
