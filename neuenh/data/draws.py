"""How measurements are drawn from a continuous measured file (an RGL ``.bsdf``, a MERL ``.binary``):
the README's protocol, 3,000 pairs, half of them with the half vector near the normal (where a glossy
material's highlight is). Names only, no torch: the command lines' help, a scene file's defaults and
the service's form fields read them; ``neuenh.study.heldout.draw_fit_test`` draws.
"""

from __future__ import annotations

DRAW_SAMPLES = 3000  # pairs drawn from each measured file
DRAW_NEAR_MIRROR = 0.5  # the share of them near the mirror direction
DRAWN_KINDS = ("rgl", "merl")  # ``formats.detect_format``'s kinds that pairs are drawn from (tables have rows)

__all__ = ["DRAWN_KINDS", "DRAW_NEAR_MIRROR", "DRAW_SAMPLES"]
