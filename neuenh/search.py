"""The hypercube search, as pure functions (paper Sec. 4.2; ARCHITECTURE §1).

A round starts from the current state B_c and builds every state within Hamming distance ``r``
of it that the constraints allow (r = 1 over binary digits: "stay" plus one flip per position,
N + 1 candidates; r = 2 adds N(N-1)/2). Each candidate is trained from B_c (``neuenh.train``);
``select`` then picks the next B_c: the lowest validation loss, optionally plus
``complexity_weight × cost``, where a change must beat "stay" by ``min_improvement`` (relative) to
be taken — so a model only grows where the data needs it. The search has converged when "stay"
wins.

Everything here is deterministic and ordered: candidates come stay first, then by distance, then
by the positions changed (in position order), so rounds reproduce exactly.
"""

from __future__ import annotations

import itertools
import math
import zlib
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

Digits = tuple[int, ...]


@dataclass(frozen=True)
class Constraints:
    """Which states a search may visit.

    ``fixed``: position index -> the digit it must keep. ``allowed``: position index -> the digits
    it may take (default: all of ``0..m-1``). ``max_neural``: at most this many neural digits, which
    are the digits in ``neural`` (default: every non-zero digit; with alternative analytical terms
    the model's module digits, ``BRDFModel.is_neural``).
    """

    fixed: Mapping[int, int] = field(default_factory=dict)
    allowed: Mapping[int, frozenset[int]] = field(default_factory=dict)
    max_neural: int | None = None
    neural: frozenset[int] | None = None

    def n_neural(self, state: Digits) -> int:
        return sum(1 for d in state if (d in self.neural if self.neural is not None else d))

    def digits_at(self, position: int, m: int) -> tuple[int, ...]:
        if position in self.fixed:
            return (self.fixed[position],)
        return tuple(d for d in range(m) if d in self.allowed.get(position, range(m)))

    def admits(self, state: Digits, m: int) -> bool:
        if self.max_neural is not None and self.n_neural(state) > self.max_neural:
            return False
        return all(d in self.digits_at(i, m) for i, d in enumerate(state))

    @classmethod
    def from_names(
        cls,
        positions: Sequence[str],
        *,
        fixed: Mapping[str, int] | None = None,
        allowed: Mapping[str, Iterable[int]] | None = None,
        max_neural: int | None = None,
        digit_counts: Sequence[int] | None = None,
        neural: Iterable[int] | None = None,
    ) -> "Constraints":
        """Constraints given by position name, as a job spec writes them. ``digit_counts``: how many
        choices each position has, when they differ (a position then never takes a digit beyond its
        own); ``neural``: the digits that count towards ``max_neural``."""
        index = {name: i for i, name in enumerate(positions)}

        def resolve(name: str) -> int:
            if name not in index:
                raise ValueError(f"unknown position {name!r}; positions are {', '.join(positions)}")
            return index[name]

        if max_neural is not None and max_neural < 0:
            raise ValueError(f"max_neural must be >= 0, got {max_neural}")
        allowed_at = {resolve(k): frozenset(int(d) for d in v) for k, v in (allowed or {}).items()}
        if digit_counts is not None and len(set(digit_counts)) > 1:
            for i, count in enumerate(digit_counts):
                allowed_at[i] = allowed_at.get(i, frozenset(range(count))) & frozenset(range(count))
        return cls(
            fixed={resolve(k): int(v) for k, v in (fixed or {}).items()},
            allowed=allowed_at,
            max_neural=max_neural,
            neural=None if neural is None else frozenset(neural),
        )


def initial_state(n_positions: int, m: int, constraints: Constraints = Constraints()) -> Digits:
    """B_c of round 0: the analytical model (all zeros), with fixed positions applied."""
    state = tuple(constraints.fixed.get(i, 0) for i in range(n_positions))
    if not constraints.admits(state, m):
        raise ValueError(
            f"no admissible start: the fixed positions need {constraints.n_neural(state)} modules "
            f"or a digit outside the allowed ones"
        )
    return state


def hamming_ball(
    center: Digits, radius: int, m: int, constraints: Constraints = Constraints()
) -> list[Digits]:
    """Every admissible state within ``radius`` of ``center``, "stay" (``center``) first.

    For m-ary digits a changed position may take any other allowed digit, so r = 1 gives
    1 + sum over positions of (allowed digits - 1) states.
    """
    if radius < 0:
        raise ValueError(f"radius must be >= 0, got {radius}")
    out = [center]
    n = len(center)
    for distance in range(1, radius + 1):
        for positions in itertools.combinations(range(n), distance):
            options = [
                [d for d in constraints.digits_at(p, m) if d != center[p]] for p in positions
            ]
            for digits in itertools.product(*options):
                state = list(center)
                for p, d in zip(positions, digits):
                    state[p] = d
                state = tuple(state)
                if constraints.admits(state, m):
                    out.append(state)
    return out


@dataclass(frozen=True)
class Outcome:
    """What selection needs of a trained candidate."""

    state: Digits
    val_loss: float  # NaN/inf or ``failed`` = not eligible
    cost: float = 0.0  # e.g. ``weight_cost``; only used when complexity_weight > 0
    failed: bool = False

    @property
    def eligible(self) -> bool:
        return not self.failed and math.isfinite(self.val_loss)

    def score(self, complexity_weight: float) -> float:
        return self.val_loss + complexity_weight * self.cost


def ranking_key(outcome: Outcome, complexity_weight: float) -> tuple:
    """Lower is better: score, then fewer modules, then the state itself (a total order)."""
    return (outcome.score(complexity_weight), sum(1 for d in outcome.state if d), outcome.state)


def select(
    outcomes: Sequence[Outcome],
    stay: Digits,
    *,
    complexity_weight: float = 0.0,
    min_improvement: float = 0.0,
) -> Outcome | None:
    """The next current state: the best eligible outcome, unless it is a change that does not
    lower the stay candidate's score by at least ``min_improvement`` (a fraction, e.g. 0.01 =
    1 %), in which case "stay" wins. ``None`` when no candidate is eligible."""
    eligible = [o for o in outcomes if o.eligible]
    if not eligible:
        return None
    best = min(eligible, key=lambda o: ranking_key(o, complexity_weight))
    stay_outcome = next((o for o in eligible if o.state == stay), None)
    if best.state == stay or stay_outcome is None:
        return best
    threshold = stay_outcome.score(complexity_weight) * (1.0 - min_improvement)
    return best if best.score(complexity_weight) < threshold else stay_outcome


def keep_better_half(outcomes: Sequence[Outcome], complexity_weight: float = 0.0) -> list[Digits]:
    """Successive halving: the states of the better half (rounded up) of the eligible outcomes,
    in ranking order. Failed candidates are dropped."""
    eligible = sorted((o for o in outcomes if o.eligible), key=lambda o: ranking_key(o, complexity_weight))
    return [o.state for o in eligible[: math.ceil(len(eligible) / 2)]]


def weight_cost(n_weights: int) -> float:
    """Cost of a state as its neural weights in thousands (the analytical model costs 0)."""
    return n_weights / 1000.0


def candidate_seed(job_seed: int, round_index: int, state: Digits) -> int:
    """A stable seed per (job, round, candidate): a re-run round trains exactly as before."""
    text = f"{job_seed}:{round_index}:{','.join(map(str, state))}"
    return zlib.crc32(text.encode()) & 0x7FFFFFFF


def describe_change(parent: str, state: str, positions: Sequence[str],
                    choice_names: Mapping[tuple[str, int], str] | None = None) -> str:
    """What ``state`` changed from ``parent``, for people (the API serves it; the dashboard and the
    CLI show it as is): ``+G`` position G became its module (digit 1), ``-G`` analytical again,
    ``+G[2]`` G became choice 2, ``G[1->2]`` another choice; several changes separated by spaces,
    ``stay`` for none. ``choice_names`` (position, digit) -> name replaces a digit by its name
    (``+D[beckmann]``)."""
    names = choice_names or {}
    out = []
    for i, (a, b) in enumerate(zip(parent, state)):
        if a == b:
            continue
        position = positions[i] if i < len(positions) else f"#{i}"
        label = lambda ch: names.get((position, int(ch, 36)), str(int(ch, 36)))  # noqa: E731
        if a == "0":
            out.append(f"+{position}" if b == "1" and (position, 1) not in names else f"+{position}[{label(b)}]")
        elif b == "0":
            out.append(f"-{position}")
        else:
            out.append(f"{position}[{label(a)}->{label(b)}]")
    return " ".join(out) or "stay"
