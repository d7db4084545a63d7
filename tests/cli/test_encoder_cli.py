"""``neuenh encoder train`` as a user runs it: the encoder lands in the bundle; bad input is one line."""

import json

import pytest
import yaml

from neuenh.checkpoint import ENCODER, Bundle
from neuenh.models import get_model
from cli_runs import neuenh, neuenh_here
from ggx_states import PAPER_STATE


@pytest.fixture
def bundle(tmp_path):
    return Bundle(get_model("ggx", state=PAPER_STATE, seed=0)).save(tmp_path / "model")


def _spec(tmp_path, data):
    path = tmp_path / "spec.yaml"
    path.write_text(yaml.safe_dump({"data": data}))
    return path


def test_train_writes_the_encoder_into_the_bundle(bundle, tmp_path):
    spec = _spec(tmp_path, [{"source": "synthetic_ggx", "materials": 4, "seed": 1},
                            {"source": "synthetic_zoo", "materials": 2, "seed": 2}])
    out = neuenh("encoder", "train", bundle, "--spec", spec, "--steps", "3", "--pool", "64", "32",
                 "--holdout", "0.34", "--threads", "1", "--json")
    assert out.returncode == 0, out.stderr
    described = json.loads(out.stdout)
    loaded = Bundle.load(bundle)
    assert (bundle / ENCODER).is_file() and loaded.encoder is not None
    record = loaded.encoder.record
    assert record["trained_on"] == 4 and len(record["heldout_materials"]) == 2
    assert set(record["heldout_log_l1"]["1"]) == {"paper", "encoder"}  # no training materials: no mean latent
    assert described["outputs"] == list(loaded.encoder.outputs)
    assert loaded.model.state == PAPER_STATE  # the rest of the bundle as it was


@pytest.mark.parametrize("data, message", [
    ([{"source": "rgl", "paths": ["x.bsdf"]}], "RGL is the validation set"),
    ([{"source": "synthetic_ggx", "materials": 1}], "leaves no material to train on"),
])
def test_unusable_training_data_is_one_line(bundle, tmp_path, data, message):
    out = neuenh_here("encoder", "train", bundle, "--spec", _spec(tmp_path, data), "--holdout", "0.9", "--steps", "1")
    assert out.returncode == 2 and message in out.stderr and "Traceback" not in out.stderr
    assert not (bundle / ENCODER).exists()


def test_a_bundle_without_a_spec_in_its_provenance_needs_one(bundle):
    out = neuenh_here("encoder", "train", bundle)
    assert out.returncode == 2 and "give one with --spec" in out.stderr


def test_not_a_bundle(tmp_path):
    out = neuenh_here("encoder", "train", tmp_path / "nothing", "--spec", tmp_path / "s.yaml")
    assert out.returncode == 2 and "neither a bundle folder nor a shipped model" in out.stderr


def test_output_writes_a_new_bundle_and_leaves_the_given_one_as_it_was(bundle, tmp_path):
    spec = _spec(tmp_path, [{"source": "synthetic_ggx", "materials": 3, "seed": 1}])
    before = {f.name: f.read_bytes() for f in bundle.iterdir()}
    out = neuenh_here("encoder", "train", bundle, "--spec", spec, "--steps", "2", "--pool", "32", "16",
                      "--holdout", "0", "-o", tmp_path / "with-encoder")
    assert out.returncode == 0, out.stderr
    assert Bundle.load(tmp_path / "with-encoder").encoder is not None
    assert {f.name: f.read_bytes() for f in bundle.iterdir()} == before


def test_a_shipped_model_by_name_needs_an_output_folder(tmp_path):
    """The shipped model's folder is part of the installation (site-packages for a wheel): training
    its encoder in place would change the model for every user of it. Refused before any work."""
    from neuenh.pretrained import bundle_path

    shipped = bundle_path("enhanced-ggx")
    if shipped is None:
        pytest.skip("no shipped models/enhanced-ggx in this tree")
    before = {f.name: f.stat().st_mtime_ns for f in shipped.iterdir()}
    out = neuenh_here("encoder", "train", "enhanced-ggx", "--spec", tmp_path / "spec.yaml")
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "enhanced-ggx is a shipped model" in out.stderr and "give -o DIR" in out.stderr
    assert {f.name: f.stat().st_mtime_ns for f in shipped.iterdir()} == before
    (tmp_path / "file").write_text("")
    out = neuenh_here("encoder", "train", "enhanced-ggx", "-o", tmp_path / "file")
    assert out.returncode == 2 and "-o " in out.stderr and "exists and is not a folder" in out.stderr


def test_the_help_names_the_steps_the_training_takes_by_default():
    """``neuenh encoder train --help`` names the default steps without importing torch
    (tests/cli/test_main.py); the training config takes them: the two numbers are one."""
    from neuenh.encoder_training import EncoderTrainConfig
    from neuenh_service.cli.encoder import DEFAULT_STEPS

    assert DEFAULT_STEPS == EncoderTrainConfig().steps
