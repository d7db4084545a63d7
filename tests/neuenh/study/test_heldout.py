"""Held-out evaluation (neuenh.study.heldout): plain GGX measurements from known parameters, fitted on
one set of rows and measured on a disjoint one; the numbers checked against numpy."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from neuenh.data.measured import TableMaterial, load_measured
from neuenh.data.directions import sample_directions
from neuenh.data.samples import Samples
from neuenh.data.table import read_table
from neuenh.study.heldout import (draw_fit_test, fit_and_evaluate, heldout_log_l1, predict_f_r, split_rows,
                             write_predictions)
from neuenh.fit import FitOptions, PlainLBFGS, fit_materials
from neuenh.materials import MaterialTable
from neuenh.models import get_model

RGL = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "rgl"
TRUE = {
    "normal": [0.03, -0.02], "t_theta": [0.4], "rho_d": [0.3, 0.2, 0.1], "rho_s": [0.6, 0.5, 0.7],
    "alpha_x": [0.12], "alpha_y": [0.25], "f0": [0.3],
}
N_ROWS, N_FIT, N_TEST = 5000, 2000, 2000
EPOCHS = 100
HELDOUT_BOUND = 0.01  # noise-free GGX fitted by GGX for 100 epochs: about 0.0015 measured


@pytest.fixture(scope="module")
def measured() -> TableMaterial:
    model = get_model("ggx")
    wi, wo = sample_directions(N_ROWS, seed=5, anisotropic=True)
    f = model.evaluate(wi, wo, {k: torch.tensor(v, dtype=torch.float64) for k, v in TRUE.items()})
    table = Samples(wi.float(), wo.float(), f.float(), torch.zeros(N_ROWS, dtype=torch.long), ("ggx-true",))
    return TableMaterial("ggx-true", table)


@pytest.fixture(scope="module")
def fitted(measured):
    model = get_model("ggx")
    fit, test, split = draw_fit_test(measured, N_FIT, N_TEST, seed=1)
    result = fit_materials(model, fit, PlainLBFGS(iterations=EPOCHS), seed=1)
    return model, fit, test, split, result


def test_split_is_disjoint_seeded_and_sized():
    fit, test = split_rows(100, 60, 30, seed=3)
    assert len(fit) == 60 and len(test) == 30
    assert not set(fit.tolist()) & set(test.tolist())
    again = split_rows(100, 60, 30, seed=3)
    assert torch.equal(fit, again[0]) and torch.equal(test, again[1])
    rest = split_rows(100, 60, None, seed=3)[1]
    assert len(rest) == 40 and set(rest.tolist()) | set(fit.tolist()) == set(range(100))
    for bad in ((60, 41), (0, 10), (10, 0)):
        with pytest.raises(ValueError, match="cannot split 100 rows"):
            split_rows(100, *bad, seed=0)


def test_fit_and_test_rows_of_a_table_are_disjoint(fitted, measured):
    _, fit, test, split, _ = fitted
    assert split == "disjoint rows" and len(fit) == N_FIT and len(test) == N_TEST
    rows = {tuple(r) for r in torch.cat([measured.table.wi, measured.table.wo], 1).tolist()}
    fit_pairs = {tuple(r) for r in torch.cat([fit.wi, fit.wo], 1).tolist()}
    test_pairs = {tuple(r) for r in torch.cat([test.wi, test.wo], 1).tolist()}
    assert len(fit_pairs) == N_FIT and len(test_pairs) == N_TEST  # no row twice
    assert fit_pairs <= rows and test_pairs <= rows and not fit_pairs & test_pairs


def test_heldout_loss_is_small_and_close_to_the_fit_loss(fitted):
    model, _, test, _, result = fitted
    (heldout,) = heldout_log_l1(model, result.materials, test)
    (fit_loss,) = result.losses
    assert heldout < HELDOUT_BOUND and fit_loss < HELDOUT_BOUND
    assert abs(heldout - fit_loss) < 0.25 * fit_loss + 1e-4


# Unit roundoff of float32, and a bound in such units on how far two float32 evaluations of one GGX
# value may disagree: the predictions come from the specialized evaluator, the loss from the training
# path, each about 50 float32 operations (the shading frame, the half vector, D, F and G), whose
# independent roundings add to ~sqrt(50) units each, so ~10 for the difference; 16 leaves room.
U32 = 2.0**-24
EVALUATORS_DISAGREE_UNITS = 16


@pytest.mark.parametrize("which", ["fitted", "initial"])
def test_heldout_loss_equals_a_numpy_computation_from_the_predictions(fitted, which):
    """mean |log(1 + f cos_i) - log(1 + f_hat cos_i)| in float64 numpy from the predictions: equal
    to rel 1e-6, and to the float32 rounding the two evaluators and the loss's logarithms add to each
    term, which matters only when the loss itself is tiny (the fitted clean table ends near 1e-6, the
    bound is ~1e-7; the unfitted initial parameters give a loss ~0.1): a term's log1p(x) is rounded
    to u log1p(x) in each of its two logarithms, and f_hat's relative disagreement of
    ``EVALUATORS_DISAGREE_UNITS`` u moves log1p(f_hat cos) by that times x / (1 + x)."""
    model, _, test, _, result = fitted
    materials = result.materials if which == "fitted" else MaterialTable(model.specs, test.names, model.latent_dim)
    pred = predict_f_r(model, materials, test).double().numpy()
    f = test.f_r.double().numpy()
    cos = np.clip(test.wi[:, 2].double().numpy(), 0, None)[:, None]
    expected = np.mean(np.abs(np.log1p(f * cos) - np.log1p(pred * cos)))
    x = f * cos
    rounding = U32 * np.mean(2 * np.log1p(x) + EVALUATORS_DISAGREE_UNITS * x / (1 + x))
    (heldout,) = heldout_log_l1(model, materials, test)
    assert heldout == pytest.approx(expected, rel=1e-6, abs=rounding)
    if which == "initial":
        assert expected > 0.05  # the comparison at rel 1e-6 is meaningful here
    else:
        # and here below the loss itself: L-BFGS stops this fit at 7-17x the bound (8e-7 on an AMD EPYC,
        # 2e-6 on an Intel Xeon, against ~1.2e-7), where the end point moves with the CPU's rounding
        assert rounding < expected


def test_predictions_are_the_model_with_the_fitted_parameters(fitted):
    model, _, test, _, result = fitted
    pred = predict_f_r(model, result.materials, test)
    direct = model.evaluate(test.wi, test.wo, result.materials.as_params(0))
    assert pred.shape == (N_TEST, 3) and not pred.requires_grad
    # the specialized evaluator, in float32: equal to evaluate to its contract (tests/neuenh/test_specialize.py)
    torch.testing.assert_close(pred, direct, rtol=1e-4, atol=1e-6 * float(direct.max()))


def test_names_must_match_the_fitted_materials(fitted):
    model, _, test, _, result = fitted
    renamed = Samples(test.wi, test.wo, test.f_r, test.material, ("other",))
    for fn in (heldout_log_l1, predict_f_r):
        with pytest.raises(ValueError, match="must be the same"):
            fn(model, result.materials, renamed)


def test_write_predictions_is_atomic_and_reads_back_as_a_table(fitted, tmp_path):
    model, _, test, _, result = fitted
    pred = predict_f_r(model, result.materials, test)
    path = write_predictions(tmp_path / "pred.npz", test, pred)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pred.npz"]
    with np.load(path, allow_pickle=False) as npz:
        assert npz["material_names"].tolist() == ["ggx-true"] and (npz["material"] == 0).all()
        np.testing.assert_array_equal(npz["f_r"], pred.numpy())
    back = read_table(path)
    assert torch.equal(back.wi, test.wi) and torch.equal(back.f_r, pred)


def test_fit_and_evaluate_a_table(measured, fitted):
    model, _, test, _, result = fitted
    out = fit_and_evaluate(get_model("ggx"), measured, N_FIT, N_TEST, seed=1, options=FitOptions(lbfgs_iterations=EPOCHS))
    assert out["split"] == "disjoint rows" and (out["n_fit"], out["n_test"]) == (N_FIT, N_TEST)
    assert out["heldout_log_l1"] < HELDOUT_BOUND and out["fit_loss"] < HELDOUT_BOUND and out["fit_s"] > 0
    # a plain model's fast fit names its protocol and budget
    assert set(out["params"]) == set(TRUE) and out["protocol"] == PlainLBFGS(iterations=EPOCHS).describe()
    # the same split, seed and config as the step-by-step fixture: the same numbers
    assert out["fit_loss"] == result.losses[0]
    assert out["heldout_log_l1"] == heldout_log_l1(model, result.materials, test)[0]
    assert out["params"]["alpha_x"][0] == pytest.approx(0.12, rel=0.2)  # the roughness is recovered


@pytest.mark.skipif(not RGL.is_dir(), reason=f"the RGL materials are not present at {RGL}")
def test_fit_and_evaluate_an_rgl_material():
    material = load_measured(RGL / "paper_white_rgb.bsdf")
    out = fit_and_evaluate(get_model("ggx"), material, 5000, 5000, seed=0, options=FitOptions(lbfgs_iterations=20))
    assert out["split"] == "independent draws" and out["n_test"] == 5000
    assert math.isfinite(out["heldout_log_l1"]) and math.isfinite(out["fit_loss"])
    assert out["heldout_log_l1"] < 1.0  # a fitted GGX, whatever its quality, is far from log-scale nonsense


def test_continuous_sources_are_drawn_at_every_azimuth():
    """Fit and test pairs of a continuous source cover phi_h, even for an isotropic material, so a
    model with anisotropic parameters cannot fit one azimuth and be tested on the same one."""
    from neuenh.data.directions import to_rusinkiewicz
    from neuenh.data.synthetic import synthetic_zoo

    (material,) = synthetic_zoo(1, seed=3, families=("oren_nayar",))
    fit, test, split = draw_fit_test(material, 2000, 2000, seed=0)
    assert split == "independent draws"
    for samples in (fit, test):
        phi_h = to_rusinkiewicz(samples.wi.double(), samples.wo.double())[1]
        assert phi_h.std() > 1.0 and torch.allclose(samples.f_r, material.evaluate(samples.wi, samples.wo).float())
