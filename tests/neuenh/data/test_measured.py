"""``load_measured``: format by content, one contract for every source, errors for the rest."""

import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from neuenh.data import load_measured
from neuenh.data.errors import DataError
from neuenh.data.measured import TableMaterial, detect_format
from neuenh.data.merl import write_merl
from neuenh.data.samples import sample_materials
from neuenh.data.table import write_table

from data_files import (
    NBRDF_WEIGHTS, RGL_DIR, hemisphere, lambertian, nbrdf_weights, shared, tiny_rgl_fields, write_tensor_file,
)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """One file per format, each under a misleading extension: detection reads content."""
    folder = tmp_path_factory.mktemp("measured")
    write_tensor_file(folder / "rgl_file.npz", tiny_rgl_fields())
    write_merl(folder / "merl_file.bsdf", lambertian())
    np.savez(folder / "nbrdf_file.binary.npz", **nbrdf_weights(["only"], seed=2))
    (folder / "nbrdf_file.binary.npz").rename(folder / "nbrdf_file.binary")
    rng = np.random.default_rng(0)
    wi, wo = hemisphere(300, 1), hemisphere(300, 2)
    write_table(folder / "table.tmp.npz", wi, wo, rng.random((300, 3)))
    (folder / "table.tmp.npz").rename(folder / "table_file.bsdf")
    return folder


SOURCES = {"rgl": "rgl_file.npz", "merl": "merl_file.bsdf", "nbrdf": "nbrdf_file.binary", "table": "table_file.bsdf"}


@pytest.mark.parametrize("kind", list(SOURCES))
def test_format_is_recognised_by_content(folder, kind):
    assert detect_format(folder / SOURCES[kind]) == kind
    material = load_measured(folder / SOURCES[kind])
    assert material.metadata["source"] == kind


@pytest.mark.parametrize("kind, table", [("rgl", False), ("merl", False), ("nbrdf", True), ("table", True)])
def test_a_table_by_its_first_bytes_with_numpy_alone(folder, tmp_path, kind, table):
    """``looks_like_table``: a zip archive (every ``.npz``: a table's, NBRDF weights) or a CSV table, told
    without the readers (and torch); the measured formats are not."""
    from neuenh.data.table import looks_like_table

    assert looks_like_table(folder / SOURCES[kind]) is table
    (tmp_path / "rows.txt").write_text("# measured\nwi_x,wi_y,wi_z,wo_x,wo_y,wo_z,r,g,b\n0,0,1,0,0,1,0.1,0.1,0.1\n")
    assert looks_like_table(tmp_path / "rows.txt") and not looks_like_table(tmp_path / "missing.npz")


@pytest.fixture(params=list(SOURCES))
def material(request, folder):
    return load_measured(folder / SOURCES[request.param])


class TestMaterialContract:
    """What every loaded material offers, whatever its source."""

    def test_identity(self, material):
        assert isinstance(material.name, str) and material.name
        assert isinstance(material.isotropic, bool) and isinstance(material.metadata, dict)
        assert Path(material.metadata["path"]).exists()

    def test_samples_are_seeded_finite_and_non_negative(self, material):
        wi, wo, f = material.samples(200, seed=4)
        assert wi.shape == wo.shape == f.shape == (200, 3)
        assert torch.isfinite(f).all() and (f >= 0).all()
        torch.testing.assert_close(torch.linalg.vector_norm(wi.double(), dim=1), torch.ones(200, dtype=torch.float64))
        assert torch.equal(f, material.samples(200, seed=4)[2])

    def test_continuous_sources_evaluate_their_samples(self, material):
        if isinstance(material, TableMaterial):
            assert not hasattr(material, "evaluate")
            return
        wi, wo, f = material.samples(100, seed=1)
        assert torch.equal(material.evaluate(wi, wo), f)
        flipped = wo.clone()
        flipped[:, 2] = -flipped[:, 2]
        assert (material.evaluate(wi, flipped) == 0).all()

    def test_feeds_a_sample_set(self, material):
        samples = sample_materials([material], 50, seed=0)
        assert len(samples) == 50 and samples.names == (material.name,)


def test_name_renames_or_selects(folder, tmp_path):
    assert load_measured(folder / SOURCES["rgl"]).name == "rgl_file"
    assert load_measured(folder / SOURCES["rgl"], name="felt").name == "felt"
    assert load_measured(folder / SOURCES["merl"], name="lamb").name == "lamb"
    assert load_measured(folder / SOURCES["table"], name="mine").name == "mine"
    assert load_measured(folder / SOURCES["nbrdf"]).name == "only"  # a single network needs no name
    path = tmp_path / "two.npz"
    np.savez(path, **nbrdf_weights(["a", "b"]))
    assert load_measured(path, name="b").name == "b"
    with pytest.raises(DataError, match="holds 2 NBRDF networks; choose one with name=... .a, b."):
        load_measured(path)
    with pytest.raises(DataError, match="no NBRDF material named 'c'"):
        load_measured(path, name="c")


def test_table_samples_are_its_rows(folder):
    material = load_measured(folder / SOURCES["table"])
    assert len(material) == 300 and not material.isotropic
    wi, wo, f = material.samples(10_000, seed=0)
    assert len(wi) == 300
    sub = material.samples(40, seed=1)
    rows = [int(np.argmin(np.abs(wi.numpy() - row).sum(1))) for row in sub[0].numpy()]
    assert rows == sorted(rows) and len(set(rows)) == 40
    assert torch.equal(sub[2], f[rows])


def test_real_files(tmp_path):
    rgl = load_measured(shared(RGL_DIR / "chm_orange_rgb.bsdf"))
    assert rgl.name == "chm_orange_rgb" and rgl.metadata["source"] == "rgl"
    chrome = load_measured(shared(NBRDF_WEIGHTS), name="chrome")
    assert chrome.name == "chrome" and chrome.metadata["source"] == "nbrdf"
    with pytest.raises(DataError, match="holds 100 NBRDF networks"):
        load_measured(NBRDF_WEIGHTS)
    alias = tmp_path / "material.dat"
    alias.symlink_to(RGL_DIR / "chm_orange_rgb.bsdf")
    assert detect_format(alias) == "rgl"


def _zip(path, members):
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return path


@pytest.mark.parametrize("case, make, message", [
    ("empty", lambda p: p.write_bytes(b""), "unrecognised content"),
    ("text", lambda p: p.write_text("theta_h theta_d phi_d r g b\n0 0 0 1 1 1\n"), "unrecognised content"),
    ("random", lambda p: p.write_bytes(np.random.default_rng(0).bytes(5000)), "unrecognised content"),
    ("other npz", lambda p: np.savez(p, x=np.zeros(3)), r"neither NBRDF weights .* a measurement table .* nor a dataset.*\[x\]"),
    ("broken zip", lambda p: p.write_bytes(b"PK\x03\x04" + b"\0" * 40), "not a readable .npz"),
    ("zip with garbage member", lambda p: _zip(p, {"wi.npy": b"nonsense", "wo.npy": b"", "f_r.npy": b""}),
     "is not a .npy array"),
    ("nbrdf with garbage member", lambda p: _zip(p, {"names.npy": b"x", "a/W1.npy": b"y"}), "is not a .npy array"),
    ("bad table", lambda p: np.savez(p, wi=np.zeros((3, 3)), wo=np.zeros((3, 3)), f_r=np.zeros((3, 3))), "unit vectors"),
    ("short merl", lambda p: p.write_bytes(b"\x5a\0\0\0\x5a\0\0\0\xb4\0\0\0" + b"\0" * 80), "truncated"),
])
def test_unusable_files_raise_data_error_naming_the_file(tmp_path, case, make, message):
    path = tmp_path / "file.npz"
    make(path)
    if not path.exists():  # np.savez appends .npz only when missing: keep the given name
        path = next(tmp_path.iterdir())
    with pytest.raises(DataError, match=message) as info:
        load_measured(path)
    assert str(path) in str(info.value)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        load_measured(tmp_path / "nothing")
    with pytest.raises(DataError, match="not a regular file"):
        load_measured(tmp_path)
