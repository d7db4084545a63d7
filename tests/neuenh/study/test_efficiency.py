"""Data-efficiency curves (``neuenh.study.efficiency``): measured on a material whose best model is
known, and summarised (medians, wins, crossover) as hand-worked tables say."""

import math

import pytest

from neuenh.data.synthetic import synthetic_ggx
from neuenh.fit import FitOptions
from neuenh.models import get_model
from neuenh.study.contenders import GraphContender, NBRDFContender
from neuenh.study.efficiency import CurvePoint, crossover, measure_curve, medians, wins
from neuenh.study.nbrdf_fit import NBRDFConfig


def test_a_curve_fits_every_contender_at_every_size_under_both_protocols():
    [material] = synthetic_ggx(1, seed=5, noise_sigma=0.0)
    contenders = [GraphContender("ggx", "GGX", "analytical", get_model("ggx"), options=FitOptions(lbfgs_iterations=60)),
                  NBRDFContender(NBRDFConfig(epochs=60))]
    points = measure_curve(material, contenders, sizes=(50, 400), n_test=600)
    assert [(p.protocol, p.n_fit, p.contender) for p in points] == [
        (protocol, n, c) for protocol in ("uniform", "mirror") for n in (50, 400) for c in ("ggx", "nbrdf")]
    for p in points:
        assert math.isfinite(p.near) and math.isfinite(p.away) and p.fit_s > 0
        # the whole is a mix of its two parts
        assert min(p.near, p.away) - 1e-12 <= p.heldout_log_l1 <= max(p.near, p.away) + 1e-12
    ggx = {(p.protocol, p.n_fit): p.heldout_log_l1 for p in points if p.contender == "ggx"}
    nbrdf = {(p.protocol, p.n_fit): p.heldout_log_l1 for p in points if p.contender == "nbrdf"}
    assert all(ggx[k] < nbrdf[k] for k in ggx)  # GGX's own material: the prior wins at every size


def point(material, n, contender, loss, protocol="uniform"):
    return CurvePoint(material, protocol, n, contender, loss, loss, loss, 1.0)


def test_medians_wins_and_crossover_follow_hand_worked_tables():
    # enhanced is ahead of NBRDF on 3/3 materials at 100, 2/3 at 1000, 0/3 at 10000
    losses = {100: ([0.1, 0.2, 0.3], [0.2, 0.3, 0.4]), 1000: ([0.1, 0.1, 0.3], [0.2, 0.2, 0.2]),
              10_000: ([0.1, 0.1, 0.1], [0.05, 0.05, 0.05])}
    points = [point(m, n, c, loss) for n, (ours, theirs) in losses.items()
              for c, row in (("enhanced", ours), ("nbrdf", theirs)) for m, loss in zip("abc", row)]
    assert wins(points, "uniform", "enhanced", "nbrdf") == {100: (3, 3), 1000: (2, 3), 10_000: (0, 3)}
    assert crossover(points, "uniform", "enhanced", "nbrdf", 2) == 1000
    assert crossover(points, "uniform", "enhanced", "nbrdf", 3) == 100
    assert crossover(points, "uniform", "nbrdf", "enhanced", 3) == 10_000
    assert crossover(points, "mirror", "enhanced", "nbrdf", 1) is None  # no such protocol measured
    assert medians(points, "uniform")["enhanced"] == {100: 0.2, 1000: 0.1, 10_000: 0.1}
    assert medians(points, "uniform")["nbrdf"][10_000] == pytest.approx(0.05)
