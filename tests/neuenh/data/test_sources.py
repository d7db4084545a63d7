"""Job-spec data sources: every kind builds through the readers, reproducibly, with unique names,
and a bad path or a file of the wrong kind is a clear error."""

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import torch
from pydantic import TypeAdapter, ValidationError

from neuenh.data.errors import DataError
from captures import capture_directions, render_capture
from neuenh.data.merl import write_merl
from neuenh.data.sources import DataSource, held_out, materialise
from neuenh.data.synthetic import ZOO_FAMILIES
from neuenh.data.table import write_table

from data_files import NBRDF_WEIGHTS, RGL_DIR, hemisphere, lambertian, nbrdf_weights, shared

SOURCE = TypeAdapter(DataSource)


def source(**fields):
    return SOURCE.validate_python(fields)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """One small file (or folder) per measured kind, written here."""
    folder = tmp_path_factory.mktemp("sources")
    write_merl(folder / "lamb.binary", lambertian())
    rng = np.random.default_rng(0)
    write_table(folder / "felt.npz", hemisphere(50, 1), hemisphere(50, 2), rng.random((50, 3)))
    write_table(folder / "silk.csv", hemisphere(30, 3), hemisphere(30, 4), rng.random((30, 3)), weight=np.ones(30))
    np.savez(folder / "nets.npz", **nbrdf_weights(["a", "b", "c"], seed=1))
    maps = {"rho_d": np.full((4, 6, 3), 0.3), "rho_s": np.full((4, 6, 3), 0.5), "alpha_x": np.full((4, 6), 0.2),
            "alpha_y": np.full((4, 6), 0.3), "f0": np.full((4, 6), 0.5), "normal": np.zeros((4, 6, 2)),
            "t_theta": np.zeros((4, 6))}
    render_capture(folder / "cap", maps, capture_directions(12, seed=0), name="tile")
    return folder


def kinds(folder: Path) -> dict:
    return {
        "nbrdf": dict(source="nbrdf", path=str(folder / "nets.npz"), materials=["c", "a"], samples=40),
        "merl": dict(source="merl", paths=[str(folder / "lamb.binary")], samples=40, seed=2),
        "table": dict(source="table", paths=[str(folder / "felt.npz"), str(folder / "silk.csv")]),
        "exr_capture": dict(source="exr_capture", path=str(folder / "cap"), region=[0, 1, 4, 6], stride=2),
    }


EXPECTED = {  # names and samples per material
    "nbrdf": (("c", "a"), 40),
    "merl": (("lamb",), 40),
    "table": (("felt", "silk"), None),
    "exr_capture": (("tile[0,1]", "tile[0,3]", "tile[0,5]", "tile[2,1]", "tile[2,3]", "tile[2,5]"), 12),
}


@pytest.mark.parametrize("kind", list(EXPECTED))
def test_each_kind_builds(files, kind):
    samples = source(**kinds(files)[kind]).build()
    names, per_material = EXPECTED[kind]
    assert samples.names == names
    counts = torch.bincount(samples.material, minlength=len(names)).tolist()
    assert counts == ([per_material] * len(names) if per_material else [50, 30])
    assert samples.f_r.dtype == torch.float32 and torch.isfinite(samples.f_r).all() and (samples.f_r >= 0).all()
    torch.testing.assert_close(torch.linalg.vector_norm(samples.wi, dim=1), torch.ones(len(samples)))


def test_tables_and_captures_subsample_their_rows_when_asked(files):
    table = source(**{**kinds(files)["table"], "samples": 20}).build()
    assert torch.bincount(table.material).tolist() == [20, 20]
    capture = source(**{**kinds(files)["exr_capture"], "samples": 5}).build()
    assert torch.bincount(capture.material).tolist() == [5] * 6


def test_nbrdf_takes_every_network_when_none_are_named(files):
    samples = source(source="nbrdf", path=str(files / "nets.npz"), samples=10, prefix="merl/").build()
    assert samples.names == ("merl/a", "merl/b", "merl/c")


def test_real_files():
    rgl = source(source="rgl", paths=[str(shared(RGL_DIR / "paper_white_rgb.bsdf")),
                                      str(RGL_DIR / "chm_orange_rgb.bsdf")], samples=300).build()
    assert rgl.names == ("paper_white_rgb", "chm_orange_rgb") and len(rgl) == 600
    nbrdf = source(source="nbrdf", path=str(shared(NBRDF_WEIGHTS)), materials=["chrome", "white-fabric"],
                   samples=300).build()
    assert nbrdf.names == ("chrome", "white-fabric")
    white = nbrdf.f_r[nbrdf.material == 1]
    assert 0.02 < float(white.mean()) < 0.5  # nearly flat near 0.11 (data README)


def test_materialise_is_seeded_and_reproducible(files):
    specs = [source(source="synthetic_zoo", materials=2, samples=100, seed=1), *(source(**k) for k in kinds(files).values())]
    a, b = materialise(specs, 0.2, seed=5), materialise(specs, 0.2, seed=5)
    assert a.names == b.names and len(a.names) == 2 + 2 + 1 + 2 + 6
    for part in ("train", "val"):
        for f in ("wi", "wo", "f_r", "material"):
            assert torch.equal(getattr(getattr(a, part), f), getattr(getattr(b, part), f))
    other = materialise([source(**{**kinds(files)["merl"], "seed": 3})], 0.2, seed=5)
    assert not torch.equal(other.train.wi, materialise([source(**kinds(files)["merl"])], 0.2, seed=5).train.wi)


def test_held_out_materials_are_a_fixed_set_kept_out_of_training(files):
    """A source's ``holdout`` materials leave training and validation; their samples are exactly the
    ones the source draws for them, whatever other sources the job holds."""
    zoo = dict(source="synthetic_zoo", materials=5, samples=120, seed=7)
    alone = materialise([source(**zoo, holdout=2)], 0.2, seed=5)
    beside = materialise([source(**kinds(files)["table"]), source(**zoo, holdout=2)], 0.2, seed=5)
    full = source(**zoo).build()
    held = alone.holdout.names
    assert len(held) == 2 and held == beside.holdout.names and set(held) < set(full.names)
    assert not set(held) & set(alone.names) and len(alone.names) == 3
    for i, name in enumerate(held):
        mine = alone.holdout.of_material(i)
        theirs = full.of_material(full.names.index(name))
        assert torch.equal(mine.wi, theirs.wi) and torch.equal(mine.f_r, theirs.f_r)
    assert materialise([source(**zoo)], 0.2, seed=5).holdout is None


def test_a_specs_names_for_the_data_are_the_ones_the_data_uses():
    """``sources.py`` writes the mirror cone and the zoo's families out so that a spec is checked
    without torch: they are those the sampling and the zoo use."""
    from neuenh.data import directions, sources

    assert sources.MIRROR_DEG == directions.MIRROR_DEG
    assert sources.ZOO_FAMILY_NAMES == tuple(ZOO_FAMILIES)


@pytest.mark.parametrize("families", [None, ["conductor", "sheen", "retro"]])
def test_a_zoo_holds_out_every_family_before_a_second_of_any(families):
    """The zoo's held-out materials cover its families round-robin (``held_out``): as many as there are
    families gives one of each, more gives each family at most one more than any other — a fit score
    must see every kind of material the source trains on."""
    kinds = families or list(ZOO_FAMILIES)
    for holdout in (len(kinds) - 1, len(kinds), 2 * len(kinds) + 1):
        zoo = source(source="synthetic_zoo", materials=40, seed=5, families=families, holdout=holdout)
        counts = Counter(kinds[i % len(kinds)] for i in held_out(zoo, 40))
        assert sum(counts.values()) == holdout and max(counts.values()) - min(counts.get(k, 0) for k in kinds) <= 1
    ggx = source(source="synthetic_ggx", materials=40, seed=4, holdout=4)  # one kind: the permutation's first
    assert held_out(ggx, 40) == sorted(torch.randperm(40, generator=torch.Generator().manual_seed(4))[:4].tolist())


@pytest.mark.parametrize("fields", [dict(source="synthetic_zoo", materials=3, holdout=3),
                                    dict(source="nbrdf", path="x.npz", materials=["a"], holdout=1)])
def test_a_source_must_keep_a_material_to_train_on(fields):
    with pytest.raises(ValueError, match="holdout .* must leave at least one of the"):
        source(**fields)


def test_names_must_be_unique_across_sources(files):
    table = kinds(files)["table"]
    with pytest.raises(ValueError, match=r"material name 'felt' occurs in data\[0\] \(table\) and data\[1\] \(table\).*prefix"):
        materialise([source(**table), source(**table)], 0.1, 0)
    data = materialise([source(**table), source(**table, prefix="again-")], 0.1, 0)
    assert data.names == ("felt", "silk", "again-felt", "again-silk")
    twin = files / "twin"
    twin.mkdir(exist_ok=True)
    write_table(twin / "felt.npz", hemisphere(5, 1), hemisphere(5, 2), np.ones((5, 3)))
    with pytest.raises(ValueError, match=r"'felt' occurs in data\[0\] \(table\) twice"):
        materialise([source(source="table", paths=[str(files / "felt.npz"), str(twin / "felt.npz")])], 0.1, 0)


@pytest.mark.parametrize("fields, match", [
    (dict(source="rgl", paths=["nowhere/x.bsdf"]), "nowhere/x.bsdf: no such file"),
    (dict(source="merl", paths=["FILES/felt.npz"]), r"felt.npz: expected a MERL .binary for a 'merl' source, but the "
                                                    "file holds a measurement table"),
    (dict(source="nbrdf", path="FILES/lamb.binary"), "lamb.binary: expected NBRDF weights"),
    (dict(source="nbrdf", path="FILES/nets.npz", materials=["zz"]), "no NBRDF material named 'zz'"),
    (dict(source="exr_capture", path="FILES"), "a folder without capture.json"),
    (dict(source="exr_capture", path="FILES/cap", region=[0, 0, 9, 9]), r"region \(0, 0, 9, 9\) is not inside the 4x6"),
], ids=["missing", "wrong-kind", "not-nbrdf", "unknown-network", "not-a-capture", "region-outside"])
def test_bad_paths_are_clear_errors(files, fields, match):
    fields = json.loads(json.dumps(fields).replace("FILES", str(files)))
    with pytest.raises(DataError, match=match) as info:
        materialise([source(**fields)], 0.1, 0)
    assert str(info.value).startswith(fields.get("path") or fields["paths"][0])


@pytest.mark.parametrize("fields, match", [
    (dict(source="rgl", paths=[]), "at least 1 item"),
    (dict(source="rgl", path="x.bsdf"), "paths\n  Field required"),
    (dict(source="merl", paths=["a", "a"]), r"paths listed twice: \['a'\]"),
    (dict(source="table", paths=["a"], samples=0), "greater than or equal to 1"),
    (dict(source="exr_capture", path="c", region=[3, 0, 1, 4]), "needs 0 <= row0 < row1"),
    (dict(source="exr_capture", path="c", stride=0), "greater than or equal to 1"),
    (dict(source="nbrdf", path="n.npz", materials=[]), "at least 1 item"),
    (dict(source="mat_lib", paths=["a"]), "does not match any of the expected tags"),
])
def test_spec_validation(fields, match):
    with pytest.raises(ValidationError, match=match):
        source(**fields)


def test_sources_round_trip_through_json(files):
    for fields in kinds(files).values():
        s = source(**fields)
        assert source(**json.loads(s.model_dump_json())) == s


@pytest.mark.parametrize("kind", ["nbrdf", "merl", "synthetic_zoo"])
def test_continuous_sources_draw_near_mirror_pairs_and_every_azimuth_when_asked(files, kind):
    fields = kinds(files).get(kind, dict(source="synthetic_zoo", materials=2, samples=40, seed=1))
    plain = source(**fields).build()
    aimed = source(**fields, near_mirror=0.5, every_azimuth=True).build()
    assert aimed.names == plain.names and len(aimed) == len(plain)
    h = aimed.wi + aimed.wo
    cos_h = h[:, 2] / torch.linalg.vector_norm(h, dim=1)
    for i in range(len(aimed.names)):
        rows = aimed.material == i
        assert int((cos_h[rows] >= np.cos(np.radians(10))).sum()) >= 20  # at least the half asked for
    assert h[:, 1].abs().max() > 0.1  # off phi_h = 0 (the isotropic ones were all at phi_h = 0 before)
    assert torch.isfinite(aimed.f_r).all() and (aimed.f_r >= 0).all()


@pytest.mark.parametrize("kind", ["table", "exr_capture"])
def test_stored_rows_cannot_be_drawn_near_the_mirror(files, kind):
    with pytest.raises(ValidationError, match="near_mirror"):
        source(**kinds(files)[kind], near_mirror=0.5)
