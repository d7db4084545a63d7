"""Issue 23's targets (``neuenh.study.targets``) judged from hand-made curves whose medians, counts
and verdicts are worked out by hand."""

from neuenh.study.efficiency import CurvePoint
from neuenh.study.targets import issue23_targets

MATERIALS = [f"m{i}" for i in range(8)]


def curve(protocol, n, contender, losses):
    return [CurvePoint(m, protocol, n, contender, loss, loss, loss, 1.0) for m, loss in zip(MATERIALS, losses)]


def flat(protocol, n, contender, loss):
    return curve(protocol, n, contender, [loss] * 8)


def test_each_target_is_met_missed_or_not_measured_as_worked_out_by_hand():
    points = [
        # uniform 10,000: adaptive 0.010 against NBRDF 0.0125 -> 0.80x, met; latent 0.018, GGX 0.036 (50 % below)
        *flat("uniform", 10_000, "enhanced-adaptive", 0.010), *flat("uniform", 10_000, "nbrdf", 0.0125),
        *flat("uniform", 10_000, "enhanced", 0.018), *flat("uniform", 10_000, "ggx", 0.036),
        # mirror 3,000: 0.030 against 0.025 -> 1.20x, missed
        *flat("mirror", 3000, "enhanced-adaptive", 0.030), *flat("mirror", 3000, "nbrdf", 0.025),
    ]
    for protocol in ("uniform", "mirror"):
        for n in (100, 300, 1000):
            points += flat(protocol, n, "nbrdf", 0.05)
            # ahead on 7 of 8 everywhere, but on 6 of 8 at mirror 1,000
            ahead = 6 if (protocol, n) == ("mirror", 1000) else 7
            points += curve(protocol, n, "enhanced-adaptive", [0.04] * ahead + [0.06] * (8 - ahead))
    points += flat("uniform", 100, "ggx", 0.045) + flat("mirror", 100, "ggx", 0.039)  # adaptive: 0.04 both
    ratio_u, ratio_m, ahead_a, ahead_l, ggx_a, ggx_l, compact = issue23_targets(points)
    assert (ratio_u.measured, ratio_u.met) == ("0.800× (0.0100 / 0.0125)", True)
    assert (ratio_m.measured, ratio_m.met) == ("1.200× (0.0300 / 0.0250)", False)
    assert (ahead_a.measured, ahead_a.met) == ("uniform 7/8, 7/8, 7/8; mirror 7/8, 7/8, 6/8", False)
    assert (ahead_l.measured, ahead_l.met) == ("uniform —, —, —; mirror —, —, —", None)  # latent not measured there
    # adaptive at 100: 0.04 against GGX 0.045 (uniform), 0.039 (mirror): worse on the mirror protocol;
    # lower than GGX on the seven materials at 0.04 (uniform), on none (mirror)
    assert (ggx_a.measured, ggx_a.met) == ("uniform 0.0400 vs 0.0450 (lower on 7/8); mirror 0.0400 vs 0.0390 (lower on 0/8)",
                                           False)
    assert ggx_l.met is None
    assert (compact.measured, compact.met) == ("0.0180 (50.0 %)", True)
    assert "| yes |" in ratio_u.markdown() and "| **no** |" in ratio_m.markdown() and "| — |" in ggx_l.markdown()


def test_the_compact_model_must_be_both_below_the_bar_and_far_enough_below_ggx():
    points = [*flat("uniform", 10_000, "enhanced", 0.019), *flat("uniform", 10_000, "ggx", 0.025)]  # 24 % below
    compact = issue23_targets(points)[-1]
    assert (compact.measured, compact.met) == ("0.0190 (24.0 %)", False)


def test_against_ggx_the_medians_judge_and_the_materials_where_each_is_lower_are_shown():
    """Lower than GGX on 6 of 8 materials, yet its median above GGX's (0.045 against 0.035): the
    issue's figure is the medians, so missed, and the row says on how many materials it was lower."""
    adaptive = [0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.10, 0.10]
    ggx = [0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.03, 0.03]
    points = [p for protocol in ("uniform", "mirror")
              for p in curve(protocol, 100, "enhanced-adaptive", adaptive) + curve(protocol, 100, "ggx", ggx)]
    ggx_a = issue23_targets(points)[4]
    assert ggx_a.measured == "uniform 0.0450 vs 0.0350 (lower on 6/8); mirror 0.0450 vs 0.0350 (lower on 6/8)"
    assert ggx_a.met is False


def test_against_ggx_on_materials_no_model_shares_gives_the_medians_alone():
    points = [p for protocol in ("uniform", "mirror")
              for p in curve(protocol, 100, "enhanced-adaptive", [0.02] * 4) + curve(protocol, 100, "ggx", [0.03] * 8)[4:]]
    ggx_a = issue23_targets(points)[4]
    assert (ggx_a.measured, ggx_a.met) == ("uniform 0.0200 vs 0.0300; mirror 0.0200 vs 0.0300", True)
