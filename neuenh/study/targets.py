"""Issue 23's targets, measured from the data-efficiency curves (``study.efficiency``) of the visible
materials: what ``neuenh report --efficiency`` states under "Where the shared model stands", and what
``bench/bench_issue23_targets.py`` prints.

Every figure is a median over the materials measured (or a count of materials), judged against the
issue's threshold; a figure whose points are missing is "not measured" and neither met nor missed.
The enhanced model is judged fitted at the adaptive capacity (``registry.ENHANCED_ADAPTIVE``) except
for the compact model's row, which is its latent fit (``registry.ENHANCED``); the rows of the
latent fit at 100 to 1,000 samples are shown beside the adaptive ones for comparison.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from typing import ClassVar
from typing import Sequence

from .efficiency import CurvePoint, medians, wins
from .registry import ENHANCED, ENHANCED_ADAPTIVE

__all__ = ["FEW_SIZES", "Target", "issue23_targets"]

FEW_SIZES = (100, 300, 1000)  # "100 to 1,000 samples"
NBRDF, GGX = "nbrdf", "ggx"


@dataclass(frozen=True)
class Target:
    figure: str
    measured: str  # as the report prints it; "not measured" when points are missing
    target: str
    met: bool | None  # None: not measured

    HEADER: ClassVar[tuple[str, str]] = ("| figure | measured | target (issue 23) | met |", "|---|---|---|---|")

    def markdown(self) -> str:
        """The target as a row of a table under ``Target.HEADER``."""
        met = "—" if self.met is None else ("yes" if self.met else "**no**")
        return f"| {self.figure} | {self.measured} | {self.target} | {met} |"


def _ratio(points: Sequence[CurvePoint], protocol: str, n: int, a: str, b: str, at_most: float, figure: str) -> Target:
    table = medians(points, protocol)
    target = f"≤ {at_most:.1f}×"
    if n not in table.get(a, {}) or n not in table.get(b, {}):
        return Target(figure, "not measured", target, None)
    ratio = table[a][n] / table[b][n]
    return Target(figure, f"{ratio:.3f}× ({table[a][n]:.4f} / {table[b][n]:.4f})", target, ratio <= at_most)


def _ahead(points: Sequence[CurvePoint], contender: str, label: str) -> Target:
    """``contender`` ahead of NBRDF on at least 7 of 8 materials at each of ``FEW_SIZES``, both protocols."""
    counts = {protocol: wins(points, protocol, contender, NBRDF) for protocol in ("uniform", "mirror")}
    cells = [f"{protocol} " + ", ".join(f"{c[n][0]}/{c[n][1]}" if n in c else "—" for n in FEW_SIZES)
             for protocol, c in counts.items()]
    found = [c[n] for c in counts.values() for n in FEW_SIZES if n in c]
    met = None if len(found) < 2 * len(FEW_SIZES) else all(8 * won >= 7 * of for won, of in found)
    return Target(f"100, 300, 1,000 samples: {label} ahead of NBRDF on (materials)", "; ".join(cells),
                  "≥ 7/8 at each size, both protocols", met)


def _against_ggx(points: Sequence[CurvePoint], contender: str, label: str, n: int = 100) -> Target:
    """``contender``'s median at ``n`` samples not above plain GGX's, both protocols. Beside the
    medians, on how many materials ``contender`` is the lower: two medians over different materials
    can order the models one way while most materials order them the other."""
    tables = {protocol: medians(points, protocol) for protocol in ("uniform", "mirror")}
    pairs = {protocol: (table.get(contender, {}).get(n), table.get(GGX, {}).get(n)) for protocol, table in tables.items()}

    def cell(protocol: str, pair: tuple) -> str:
        if None in pair:
            return f"{protocol} —"
        lower = wins(points, protocol, contender, GGX).get(n)  # None: no material measured by both
        return f"{protocol} {pair[0]:.4f} vs {pair[1]:.4f}" + (f" (lower on {lower[0]}/{lower[1]})" if lower else "")

    cells = [cell(protocol, pair) for protocol, pair in pairs.items()]
    met = None if any(None in v for v in pairs.values()) else all(a <= b for a, b in pairs.values())
    return Target(f"{n} samples: {label} against plain GGX (medians)", "; ".join(cells), "not worse", met)


def _compact(points: Sequence[CurvePoint], n: int = 10_000) -> Target:
    """The latent fit at ``n`` uniform samples: its median, and the median over materials of its
    reduction against plain GGX's error on the same material."""
    figure = f"latent-only (compact) model, uniform {n:,}: median (median reduction against GGX)"
    target = "≤ 0.0195, and ≥ 40 % below GGX"
    per: dict[str, dict[str, float]] = {}
    for p in points:
        if p.protocol == "uniform" and p.n_fit == n and p.contender in (ENHANCED, GGX):
            per.setdefault(p.material, {})[p.contender] = p.heldout_log_l1
    pairs = [v for v in per.values() if len(v) == 2]
    if not pairs:
        return Target(figure, "not measured", target, None)
    median = statistics.median(v[ENHANCED] for v in per.values() if ENHANCED in v)
    reduction = statistics.median(1 - v[ENHANCED] / v[GGX] for v in pairs)
    return Target(figure, f"{median:.4f} ({100 * reduction:.1f} %)", target, median <= 0.0195 and reduction >= 0.40)


def issue23_targets(points: Sequence[CurvePoint]) -> list[Target]:
    """Issue 23's targets that the curves measure, in the issue's order (module doc); the scene
    example's row is the plan's (``docs/scene-example/plan.md``), not the curves'."""
    return [
        _ratio(points, "uniform", 10_000, ENHANCED_ADAPTIVE, NBRDF, 1.0,
               "uniform, 10,000 samples: enhanced (adaptive) / NBRDF (medians)"),
        _ratio(points, "mirror", 3000, ENHANCED_ADAPTIVE, NBRDF, 1.1,
               "mirror, 3,000 samples: enhanced (adaptive) / NBRDF (medians)"),
        _ahead(points, ENHANCED_ADAPTIVE, "enhanced (adaptive)"),
        _ahead(points, ENHANCED, "enhanced (latent)"),
        _against_ggx(points, ENHANCED_ADAPTIVE, "enhanced (adaptive)"),
        _against_ggx(points, ENHANCED, "enhanced (latent)"),
        _compact(points),
    ]
