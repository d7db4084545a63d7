import hashlib
import json
import os

import pytest
import torch

from neuenh.checkpoint import Bundle, BundleError
from neuenh.data.directions import sample_directions
from neuenh.materials import MaterialTable
from neuenh.models import get_model
from ggx_states import PAPER_STATE


@pytest.fixture()
def bundle():
    model = get_model("ggx", state=PAPER_STATE, seed=2)
    table = MaterialTable(model.specs, ["a", "b"], model.latent_dim)
    with torch.no_grad():
        for p in table.parameters():
            p.add_(torch.randn(p.shape, generator=torch.Generator().manual_seed(1)))
    return Bundle(model, table, training={"epochs": 3}, metrics={"val_loss": 0.1})


def _same(a: Bundle, b: Bundle):
    assert a.model.state == b.model.state and a.materials.names == b.materials.names
    for key, value in a.model.neural.state_dict().items():
        assert torch.equal(value, b.model.neural.state_dict()[key])
    for key, value in a.materials.tensors().items():
        assert torch.equal(value, b.materials.tensors()[key])
    wi, wo = sample_directions(100, seed=0)
    params = a.materials.as_params(1)
    assert torch.equal(a.model.evaluate(wi.float(), wo.float(), params),
                       b.model.evaluate(wi.float(), wo.float(), b.materials.as_params(1)))


def test_directory_round_trip_is_exact(bundle, tmp_path):
    bundle.save(tmp_path / "m")
    assert sorted(os.listdir(tmp_path / "m")) == ["materials.safetensors", "model.json", "weights.safetensors"]
    loaded = Bundle.load(tmp_path / "m")
    _same(bundle, loaded)
    assert loaded.metrics == {"val_loss": 0.1} and loaded.training == {"epochs": 3}
    meta = json.loads((tmp_path / "m" / "model.json").read_text())
    assert meta["state"] == PAPER_STATE and meta["latent_dim"] == 27 and len(meta["positions"]) == 11


def test_bytes_round_trip_is_exact(bundle):
    _same(bundle, Bundle.from_bytes(bundle.to_bytes()))


def test_saving_leaves_no_temporary_files(bundle, tmp_path):
    bundle.save(tmp_path)
    bundle.save(tmp_path)
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".")]


def test_a_bundle_without_materials(tmp_path):
    Bundle(get_model("ward")).save(tmp_path)
    loaded = Bundle.load(tmp_path)
    assert loaded.materials is None and loaded.model.name == "ward"


@pytest.mark.parametrize(
    "damage,match",
    [
        (lambda d: (d / "model.json").unlink(), "not a model bundle"),
        (lambda d: (d / "model.json").write_text("{"), "not valid JSON"),
        (lambda d: (d / "weights.safetensors").write_bytes(b"\x00" * 20), "weights.safetensors"),
        (lambda d: (d / "weights.safetensors").unlink(), "weights.safetensors: missing"),
        (lambda d: _edit_json(d, state="00000000000"), "weights do not match"),
        (lambda d: _edit_json(d, model="nope"), "unknown model"),
        (lambda d: _edit_json(d, param_specs=[]), "parameter specs differ"),
        (lambda d: _edit_json(d, format="zip"), "not a neuenh-bundle"),
    ],
    ids=["no-json", "bad-json", "corrupt-weights", "no-weights", "state-mismatch", "unknown-model",
         "spec-mismatch", "format"],
)
def test_damaged_bundles_raise_a_clear_error(bundle, tmp_path, damage, match):
    bundle.save(tmp_path)
    damage(tmp_path)
    with pytest.raises(BundleError, match=match):
        Bundle.load(tmp_path)


def _edit_json(directory, **changes):
    meta = json.loads((directory / "model.json").read_text())
    meta.update(changes)
    (directory / "model.json").write_text(json.dumps(meta))


def test_a_save_killed_half_way_is_refused_not_loaded_as_a_mix(bundle, tmp_path):
    """The weights of another save beside this save's model.json (a kill between the two files'
    renames) load as neither model: the digest in model.json names the file."""
    bundle.save(tmp_path / "a")
    other = Bundle(get_model("ggx", state=PAPER_STATE, seed=9), bundle.materials)
    other.save(tmp_path / "b")
    os.replace(tmp_path / "b" / "weights.safetensors", tmp_path / "a" / "weights.safetensors")
    with pytest.raises(BundleError, match="weights.safetensors: does not match model.json"):
        Bundle.load(tmp_path / "a")


def test_a_flipped_byte_in_the_tensor_data_is_refused(bundle, tmp_path):
    """Still a valid safetensors file, different numbers: refused, never used silently."""
    bundle.save(tmp_path)
    path = tmp_path / "materials.safetensors"
    data = bytearray(path.read_bytes())
    data[-3] ^= 0x10  # inside the last tensor's values
    path.write_bytes(bytes(data))
    with pytest.raises(BundleError, match="materials.safetensors: does not match model.json"):
        Bundle.load(tmp_path)


def test_saved_files_are_readable_by_colleagues(bundle, tmp_path):
    """They were written mode 0600 (mkstemp's), so a shared model folder was unreadable to others
    (issue 17, case 15)."""
    import stat

    bundle.save(tmp_path)
    for name in ("model.json", "weights.safetensors", "materials.safetensors"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) & 0o044 == 0o044, name


def test_a_rung_written_before_stop_57_keeps_its_mean_code_as_its_one_training_code(tmp_path):
    """Bundles of earlier versions stored each rung's training codes' mean (``<k>.latent_mean``): read
    as one code, so a fit with that rung starts from the mean as it did; a malformed one is refused."""
    from safetensors.torch import load_file, save_file

    from neuenh.checkpoint import Rung

    base = Bundle.initial("ggx", ["a", "b"])
    one = base.model.enhance("00000100000", seed=1)
    folder = Bundle(one, base.materials, rungs=[Rung.of(0, 0.03, Bundle(one, base.materials))]).save(tmp_path / "m")
    tensors = load_file(folder / "rungs.safetensors")
    codes = tensors.pop("0.latent_codes")
    for mean, accepted in ((codes.mean(0) + 1.0, True), (torch.zeros(5), False)):
        save_file({**tensors, "0.latent_mean": mean}, folder / "rungs.safetensors")
        meta = json.loads((folder / "model.json").read_text())
        meta["digests"]["rungs.safetensors"] = hashlib.sha256((folder / "rungs.safetensors").read_bytes()).hexdigest()
        (folder / "model.json").write_text(json.dumps(meta))
        if accepted:
            [rung] = Bundle.load(folder).rungs
            assert torch.equal(rung.latent_codes, mean.reshape(1, 27)) and torch.equal(rung.trained().mean_latent(), mean)
        else:
            with pytest.raises(BundleError, match=r"rung 0: latent codes of shape \(1, 5\), expected \(k, 27\)"):
                Bundle.load(folder)


def test_rungs_travel_with_the_bundle_on_disk_and_on_the_wire(tmp_path):
    """A bundle's rungs keep their states, weights, losses and training codes; a tampered rungs file is
    refused by name."""
    from neuenh.checkpoint import Rung

    base = Bundle.initial("ggx", ["a", "b", "c"])
    one = base.model.enhance("00000100000", seed=1)
    two = one.enhance("00001100100", seed=2)
    with torch.no_grad():
        base.materials.latent[1] = 2.0
    rungs = [Rung.of(0, 0.05, Bundle(base.model, base.materials)), Rung.of(1, 0.03, Bundle(one, base.materials)),
             Rung.of(3, 0.02, Bundle(two, base.materials))]
    bundle = Bundle(two, base.materials, rungs=rungs)
    for back in (Bundle.load(bundle.save(tmp_path / "m")), Bundle.from_bytes(bundle.to_bytes())):
        assert [(r.round, r.state, r.val_loss) for r in back.rungs] == [(0, "00000000000", 0.05),
                                                                       (1, "00000100000", 0.03),
                                                                       (3, "00001100100", 0.02)]
        assert back.rungs[0].latent_codes is None and back.rungs[0].trained() is None  # no module reads the latent
        assert torch.equal(back.rungs[1].latent_codes, torch.tensor([0.5, 2.0, 0.5]).repeat_interleave(27).reshape(3, 27))
        assert torch.equal(back.rungs[1].trained().latent_codes(), back.rungs[1].latent_codes)
        for got, want in zip(back.rungs, rungs):
            for (k, v), (k2, v2) in zip(got.model.neural.state_dict().items(), want.model.neural.state_dict().items()):
                assert k == k2 and torch.equal(v, v2)
    meta = (tmp_path / "m" / "model.json").read_text()
    assert '"params_per_material": 39' in meta and '"rungs"' in meta
    data = bytearray((tmp_path / "m" / "rungs.safetensors").read_bytes())
    data[-5] ^= 0xFF
    (tmp_path / "m" / "rungs.safetensors").write_bytes(bytes(data))
    with pytest.raises(BundleError, match="rungs.safetensors: does not match model.json"):
        Bundle.load(tmp_path / "m")
