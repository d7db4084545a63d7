import math

import pytest

from neuenh.models import get_model
from neuenh.search import (
    describe_change,
    Constraints,
    Outcome,
    candidate_seed,
    hamming_ball,
    initial_state,
    keep_better_half,
    select,
)

GGX = get_model("ggx").positions
ZERO = (0,) * 11


@pytest.mark.parametrize("radius,m,expected", [(0, 2, 1), (1, 2, 12), (2, 2, 67), (3, 2, 232), (1, 3, 23)])
def test_ball_sizes(radius, m, expected):
    # Binary r=1: N+1; r=2 adds N(N-1)/2 (paper Sec. 4.2); m-ary r=1: 1 + N(m-1).
    ball = hamming_ball(ZERO, radius, m)
    assert len(ball) == expected == len(set(ball))
    assert ball[0] == ZERO
    assert all(sum(a != b for a, b in zip(s, ZERO)) <= radius for s in ball)


def test_ball_order_is_stable_and_by_distance():
    ball = hamming_ball(ZERO, 2, 2)
    assert ball == hamming_ball(ZERO, 2, 2)
    distances = [sum(s) for s in ball]
    assert distances == sorted(distances)
    assert ball[1] == (1,) + (0,) * 10


def test_one_step_can_also_revert_a_module():
    center = (0, 0, 0, 1, 1, 1, 0, 0, 1, 0, 0)
    ball = hamming_ball(center, 1, 2)
    assert (0, 0, 0, 0, 1, 1, 0, 0, 1, 0, 0) in ball  # F back to analytical
    assert len(ball) == 12


def test_constraints_fixed_allowed_and_max_neural():
    c = Constraints.from_names(GGX, fixed={"M": 0, "invE": 1}, allowed={"D": [0]}, max_neural=2)
    start = initial_state(11, 2, c)
    assert start == (0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0)
    ball = hamming_ball(start, 2, 2, c)
    assert all(s[0] == 0 and s[5] == 1 and s[2] == 0 and sum(s) <= 2 for s in ball)
    # Free positions: 11 - M, invE, D = 8; within max 2 modules only one more flip fits.
    assert len(ball) == 1 + 8


def test_constraint_errors_name_the_problem():
    with pytest.raises(ValueError, match="unknown position 'Q'"):
        Constraints.from_names(GGX, fixed={"Q": 1})
    with pytest.raises(ValueError, match="no admissible start"):
        initial_state(11, 2, Constraints.from_names(GGX, fixed={"F": 1, "G": 1}, max_neural=1))


def _o(state, loss, cost=0.0, failed=False):
    return Outcome(tuple(int(c) for c in state), loss, cost, failed)


def test_lowest_validation_loss_wins():
    outcomes = [_o("00", 0.5), _o("10", 0.3), _o("01", 0.4)]
    assert select(outcomes, (0, 0)).state == (1, 0)


def test_failed_and_non_finite_candidates_never_win():
    outcomes = [_o("00", 0.5), _o("10", 0.1, failed=True), _o("01", math.nan), _o("11", math.inf)]
    assert select(outcomes, (0, 0)).state == (0, 0)
    assert select([_o("10", math.nan)], (0, 0)) is None


def test_complexity_weight_trades_loss_for_size():
    outcomes = [_o("00", 0.50), _o("10", 0.45, cost=7.0), _o("01", 0.47, cost=1.0)]
    assert select(outcomes, (0, 0)).state == (1, 0)
    assert select(outcomes, (0, 0), complexity_weight=0.01).state == (0, 1)
    assert select(outcomes, (0, 0), complexity_weight=0.1).state == (0, 0)


def test_min_improvement_keeps_the_current_state():
    outcomes = [_o("00", 0.50), _o("10", 0.49)]
    assert select(outcomes, (0, 0), min_improvement=0.01).state == (1, 0)  # 2 % better
    assert select(outcomes, (0, 0), min_improvement=0.05).state == (0, 0)


def test_ties_prefer_fewer_modules():
    assert select([_o("11", 0.3), _o("10", 0.3), _o("00", 0.4)], (0, 0)).state == (1, 0)


def test_keep_better_half():
    outcomes = [_o("00", 0.5), _o("10", 0.3), _o("01", 0.4), _o("11", 0.2), _o("20", math.nan)]
    assert keep_better_half(outcomes) == [(1, 1), (1, 0)]


def test_candidate_seeds_are_stable_and_distinct():
    assert candidate_seed(0, 3, (0, 1)) == candidate_seed(0, 3, (0, 1))
    seeds = {candidate_seed(0, r, s) for r in range(3) for s in hamming_ball(ZERO, 1, 2)}
    assert len(seeds) == 36


@pytest.mark.parametrize("parent, state, names, expected", [
    ("00000000000", "00000000000", None, "stay"),
    ("00000000000", "00000100000", None, "+invE"),
    ("00001100000", "00000100000", None, "-G"),
    ("00001100000", "00002100000", None, "G[1->2]"),
    ("00000000000", "00200000100", None, "+D[2] +S*D*F*G"),
    ("00000000000", "00200000000", {("D", 2): "beckmann"}, "+D[beckmann]"),
    ("00100000000", "00200000000", {("D", 1): "ggx16", ("D", 2): "beckmann"}, "D[ggx16->beckmann]"),
])
def test_describe_change(parent, state, names, expected):
    assert describe_change(parent, state, GGX, names) == expected
