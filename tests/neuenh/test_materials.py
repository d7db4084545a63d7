"""The per-material record (``MaterialParams``) and its travel through tables and bundles.

Layers: (1) the record validates itself on construction and names what is wrong; (2) its counts
follow from its parts (``n_params``; a low-rank fit's own count of its corrections); (3) it
round-trips through plain data (fit reports, plans) and, with corrections, through a bundle's
materials file (safetensors) and its bytes; a bundle without corrections loads as before.
"""

from __future__ import annotations

import math

import pytest
import torch

from neuenh.checkpoint import Bundle, BundleError
from neuenh.data.directions import sample_directions
from neuenh.materials import MaterialParams, MaterialTable
from neuenh.models import get_model
from ggx_states import PAPER_STATE

VALUES = {"rho_d": torch.tensor([0.2, 0.3, 0.4]), "alpha_x": torch.tensor([0.1])}


@pytest.mark.parametrize("make, message", [
    (lambda: MaterialParams({"rho_d": torch.tensor([0.2, math.nan, 0.4])}), "parameter 'rho_d' has non-finite"),
    (lambda: MaterialParams(VALUES, torch.tensor([0.5, math.inf])), "latent code has non-finite"),
    (lambda: MaterialParams({"rho_d": torch.zeros(2, 2, 3)}), r"'rho_d' must be \(width,\)"),
    (lambda: MaterialParams(VALUES, None, {"F.layers.0.weight": torch.tensor([math.nan])}), "correction 'F.layers"),
    (lambda: MaterialParams({"rho_d": torch.zeros(5, 3)}, None, {"F.layers.0.bias": torch.zeros(16)}),
     "corrections belong to one material"),
    (lambda: MaterialParams(VALUES, correction_params=4), "no corrections"),
    (lambda: MaterialParams(VALUES, None, {"F.layers.0.bias": torch.zeros(16)}, correction_params=-1), "count >= 0"),
    (lambda: MaterialParams({**VALUES, "latent": torch.zeros(27)}), "latent=..."),
    (lambda: MaterialParams.of({**VALUES, "latent": torch.zeros(27)}), "MaterialParams"),
    (lambda: MaterialParams.from_json({"params": {**{k: v.tolist() for k, v in VALUES.items()}, "latent": [0.5]}}),
     "write it again"),
    (lambda: MaterialParams.from_json({"params": {"rho_d": ["x"]}}), "material parameters"),
    (lambda: MaterialParams(VALUES, capacity=""), "capacity"),
])
def test_a_bad_record_is_refused_naming_what_is_wrong(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_counts_and_derived_capacity():
    plain = MaterialParams(VALUES)
    assert (plain.capacity, plain.n_params) == ("analytical", 4)
    latent = MaterialParams(VALUES, torch.zeros(27))
    assert (latent.capacity, latent.n_params) == ("latent", 31)
    dense = MaterialParams(VALUES, torch.zeros(27), {"F.layers.3.weight": torch.zeros(1, 16)}, "last-layer")
    assert (dense.capacity, dense.n_params) == ("last-layer", 31 + 16)
    # a rank-1 correction of a 16x32 weight: the factors' 16 + 32 numbers, not the 512 of the delta
    low_rank = MaterialParams(VALUES, torch.zeros(27), {"F.layers.1.weight": torch.zeros(32, 16)}, "rank-1",
                              correction_params=48)
    assert low_rank.n_params == 31 + 48
    assert MaterialParams({"f0": 0.5}).values["f0"].shape == (1,)  # a scalar is a width-1 value


def test_what_a_state_reads():
    """``used_params``: the values the state reads, the latent code only if a module reads it; the
    count is then the state's (39 for the paper's enhanced GGX, 12 for plain GGX)."""
    enhanced = get_model("ggx", state=PAPER_STATE)
    table = MaterialTable(enhanced.specs, ["a"], 27)
    record = table.as_params(0)
    assert enhanced.used_params(record).n_params == enhanced.n_material_params() == 39
    plain = get_model("ggx").used_params(record)
    assert plain.latent is None and plain.capacity == "analytical" and plain.n_params == 12


def test_plain_data_round_trip_is_exact():
    record = MaterialParams(VALUES, torch.rand(27), {"F.layers.3.bias": torch.randn(1)}, "last-layer", 17)
    back = MaterialParams.from_json(record.to_json())
    assert back.values.keys() == record.values.keys() and all(torch.equal(back.values[k], v)
                                                              for k, v in record.values.items())
    assert torch.equal(back.latent, record.latent) and torch.equal(back.corrections["F.layers.3.bias"],
                                                                   record.corrections["F.layers.3.bias"])
    assert (back.capacity, back.correction_params, back.n_params) == ("last-layer", 17, record.n_params)


@pytest.fixture()
def corrected():
    """A bundle of the paper's enhanced GGX whose second material corrects two module weights."""
    model = get_model("ggx", state=PAPER_STATE, seed=2)
    table = MaterialTable(model.specs, ["a", "b", "c"], model.latent_dim)
    generator = torch.Generator().manual_seed(3)
    deltas = {key: 0.1 * torch.randn(model.neural.state_dict()[key].shape, generator=generator)
              for key in ("F.layers.3.weight", "invE.layers.3.bias")}
    table.set_corrections(1, deltas, "last-layer", 17)
    return Bundle(model, table)


@pytest.mark.parametrize("how", ["directory", "bytes"])
def test_corrections_round_trip_through_a_bundle(corrected, how, tmp_path):
    back = Bundle.load(corrected.save(tmp_path / "b")) if how == "directory" else \
        Bundle.from_bytes(corrected.to_bytes())
    wi, wo = (w.float() for w in sample_directions(200, seed=0))
    for i in range(3):
        want, got = corrected.materials.as_params(i), back.materials.as_params(i)
        assert got.corrections.keys() == want.corrections.keys()
        assert all(torch.equal(got.corrections[k], d) for k, d in want.corrections.items())
        assert (got.capacity, got.correction_params) == (want.capacity, want.correction_params)
        assert torch.equal(back.model.evaluate(wi, wo, got), corrected.model.evaluate(wi, wo, want))
    assert back.materials.as_params(1).capacity == "last-layer" and back.materials.as_params(0).capacity == "latent"
    assert not torch.equal(back.model.evaluate(wi, wo, back.materials.as_params(1)),
                           back.model.evaluate(wi, wo, MaterialParams(back.materials.as_params(1).values,
                                                                      back.materials.as_params(1).latent)))


def test_a_correction_of_a_weight_the_model_lacks_is_refused_on_load(corrected, tmp_path):
    corrected.materials.set_corrections(0, {"D.layers.0.weight": torch.zeros(16, 45)})  # D is no module here
    with pytest.raises(BundleError, match="D.layers.0.weight"):
        Bundle.load(corrected.save(tmp_path / "b"))


def test_a_bundle_without_corrections_has_the_files_it_always_had(tmp_path):
    model = get_model("ggx", state=PAPER_STATE, seed=2)
    Bundle(model, MaterialTable(model.specs, ["a"], 27)).save(tmp_path)
    from safetensors import safe_open

    with safe_open(tmp_path / "materials.safetensors", framework="pt") as f:
        assert sorted(f.metadata()) == ["names"] and not [k for k in f.keys() if k.startswith("correction.")]
    assert Bundle.load(tmp_path).materials.as_params(0).corrections == {}


def test_tables_join_in_order_with_every_record():
    """``MaterialTable.concat``: the materials of each table in order, values, latent codes and
    corrections (with capacity and count) as they were; tables of another model are refused."""
    model = get_model("ggx", state=PAPER_STATE)
    first, second = MaterialTable(model.specs, ["a", "b"], 27), MaterialTable(model.specs, ["c"], 27)
    with torch.no_grad():
        second.latent.fill_(0.25)
        second.raw["rho_d"].fill_(-1.0)
    second.set_corrections(0, {"F.layers.3.bias": torch.ones(1)}, "last-layer", 1)
    joined = MaterialTable.concat([first, second])
    assert joined.names == ("a", "b", "c")
    for i, (table, j) in enumerate([(first, 0), (first, 1), (second, 0)]):
        mine, theirs = joined.as_params(i), table.as_params(j)
        assert all(torch.equal(mine.values[k], v) for k, v in theirs.values.items())
        assert torch.equal(mine.latent, theirs.latent) and (mine.capacity, mine.n_params) == (theirs.capacity,
                                                                                               theirs.n_params)
    assert torch.equal(joined.as_params(2).corrections["F.layers.3.bias"], torch.ones(1))
    with pytest.raises(ValueError, match="different models"):
        MaterialTable.concat([first, MaterialTable(get_model("ward").specs, ["w"], 27)])


def test_a_material_fitted_at_an_analytical_capacity_holds_no_latent_code(corrected, tmp_path):
    """A bundle's material fitted at the ``original`` capacity keeps its record through a save, and
    the model's mean code and training codes leave its row out: it is only where its fit started."""
    with torch.no_grad():
        corrected.materials.latent.copy_(torch.tensor([[0.2], [0.4], [100.0]]).expand(-1, 27))
    corrected.materials.set_corrections(2, {}, "original")
    back = Bundle.load(corrected.save(tmp_path / "b")).materials
    assert back.as_params(2).capacity == "original" and back.coded() == [0, 1]
    assert torch.equal(back.latent_codes(), back.latent.detach()[:2])
    assert torch.allclose(back.mean_latent(), torch.full((27,), 0.3))
    back.set_corrections(0, {}, "analytical")
    back.set_corrections(1, {}, "original")
    assert back.coded() == [] and back.latent_codes().shape == (0, 27) and back.mean_latent() is None
