"""MERL ``.binary``: writing analytical BRDFs, reading them back, nearest-bin lookup, phi_d
folding, invalid bins and broken files."""

import math
import struct

import numpy as np
import pytest
import torch

from neuenh.data.errors import DataError
from neuenh.data.merl import (
    DIMS, FILE_SIZE, N_BINS, SCALE, MERLError, bin_centre_directions, bin_centres, bin_indices, direction_bins,
    flat_index,
    load_merl, read_merl, write_merl,
)
from neuenh.data.directions import from_rusinkiewicz, to_rusinkiewicz
from neuenh.models import get_model

from data_files import hemisphere, lambertian

GGX_PARAMS = {
    "normal": torch.tensor([0.0, 0.0]), "t_theta": torch.tensor([0.0]),
    "rho_d": torch.tensor([0.1, 0.2, 0.3]), "rho_s": torch.tensor([0.9, 0.7, 0.5]),
    "alpha_x": torch.tensor([0.12]), "alpha_y": torch.tensor([0.12]), "f0": torch.tensor([0.4]),
}


def ggx(wi, wo):
    with torch.no_grad():
        return get_model("ggx").evaluate(wi, wo, GGX_PARAMS)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("merl")
    return {"ggx": write_merl(folder / "ggx.binary", ggx),
            "lambertian": write_merl(folder / "lambertian.binary", lambertian())}


@pytest.fixture(scope="module")
def centres():
    return bin_centre_directions()


def merl_reference_bin(wi, wo) -> int:
    """The MERL reference lookup (BRDFRead.cpp) for one pair, written out with rotations and
    Python's int(), plus the README's fold of phi_d into [0, pi)."""
    def rotate(v, axis, angle):  # Rodrigues
        axis = np.asarray(axis, dtype=float)
        return (v * math.cos(angle) + np.cross(axis, v) * math.sin(angle)
                + axis * np.dot(axis, v) * (1 - math.cos(angle)))

    h = (wi + wo) / np.linalg.norm(wi + wo)
    theta_h, phi_h = math.acos(min(1.0, h[2])), math.atan2(h[1], h[0])
    d = rotate(rotate(wi, [0, 0, 1], -phi_h), [0, 1, 0], -theta_h)
    theta_d, phi_d = math.acos(max(-1.0, min(1.0, d[2]))), math.atan2(d[1], d[0])
    i_h = min(max(int(math.sqrt(theta_h / (math.pi / 2)) * 90), 0), 89)
    i_d = min(max(int(theta_d / (math.pi / 2) * 90), 0), 89)
    if phi_d < 0:
        phi_d += math.pi
    if phi_d >= math.pi:
        phi_d -= math.pi
    i_p = min(max(int(phi_d / math.pi * 180), 0), 179)
    return (i_h * 90 + i_d) * 180 + i_p


# -- writing and reading back -----------------------------------------------------------------
def test_file_layout(files):
    content = files["lambertian"].read_bytes()
    assert len(content) == FILE_SIZE == 12 + 3 * 1_458_000 * 8
    assert struct.unpack_from("<3i", content) == (90, 90, 180)
    raw = np.frombuffer(content, "<f8", offset=12).reshape(3, N_BINS)
    valid = raw[0] >= 0
    values = raw[:, valid] * SCALE[:, None]
    np.testing.assert_allclose(values, np.broadcast_to(np.array([[0.2], [0.5], [0.8]]) / math.pi, values.shape), rtol=1e-15)


@pytest.mark.parametrize("name, fn", [("ggx", ggx), ("lambertian", lambertian())])
def test_round_trip_at_bin_centres(files, centres, name, fn):
    """Read back, every bin centre above the horizon holds the model's value to float64
    precision; the others are marked invalid (negative) and evaluate to 0."""
    wi, wo = centres
    above = ((wi[:, 2] > 0) & (wo[:, 2] > 0)).numpy()
    expected = fn(wi, wo).numpy()
    table = read_merl(files[name])
    assert table.shape == (3, *DIMS) and table.dtype == np.float64
    flat = table.reshape(3, N_BINS).T
    np.testing.assert_allclose(flat[above], expected[above], rtol=4e-16, atol=0)
    assert (flat[~above] < 0).all()
    material = load_merl(files[name])
    f = material.evaluate(wi, wo).numpy()
    np.testing.assert_allclose(f[above], expected[above], rtol=4e-16, atol=0)
    assert (f[~above] == 0).all()
    assert not material.valid(wi, wo).numpy()[~above].any()
    assert 0.70 < material.valid_fraction < 0.80


def test_bin_centres_fall_into_their_own_bins(centres):
    np.testing.assert_array_equal(direction_bins(*centres), np.arange(N_BINS))
    for got, expected in zip(bin_indices(*bin_centres()), np.meshgrid(*map(np.arange, DIMS), indexing="ij")):
        np.testing.assert_array_equal(got, expected)


def test_writer_accepts_a_table_and_rejects_bad_models(tmp_path):
    table = np.full((3, *DIMS), 0.25)
    table[:, 3, 4, 5] = -1.0
    material = load_merl(write_merl(tmp_path / "t.binary", table))
    np.testing.assert_allclose(material.table[:, 0, 0, 0], 0.25, rtol=1e-15)
    assert (material.table[:, 3, 4, 5] < 0).all()
    with pytest.raises(ValueError, match="shape"):
        write_merl(tmp_path / "bad.binary", lambda wi, wo: torch.zeros(len(wi), 2))
    with pytest.raises(ValueError, match="non-finite"):
        write_merl(tmp_path / "bad.binary", lambda wi, wo: torch.full((len(wi), 3), float("nan")))
    assert not (tmp_path / "bad.binary").exists()


# -- lookup ------------------------------------------------------------------------------------
def test_nearest_bin_lookup_matches_the_reference_rule(files):
    """Random pairs: the bin is the MERL reference code's, and the value is that bin's."""
    wi, wo = hemisphere(400, 0), hemisphere(400, 1)
    bins = direction_bins(wi, wo)
    assert bins.tolist() == [merl_reference_bin(a, b) for a, b in zip(wi, wo)]
    material = load_merl(files["ggx"])
    table = material.table.reshape(3, N_BINS).T
    f = material.evaluate(torch.from_numpy(wi), torch.from_numpy(wo)).numpy()
    np.testing.assert_array_equal(f, np.clip(table[bins], 0, None))


def test_index_rules_at_known_angles():
    th = np.array([0.0, (0.5 / 90) ** 2 * math.pi / 2, math.pi / 2, 2.0])
    td = np.array([0.0, 0.5 / 90 * math.pi / 2, math.pi / 2, 2.0])
    pd = np.array([0.0, 0.5 / 180 * math.pi, math.pi - 1e-9, -1e-9])
    i_h, i_d, i_p = bin_indices(th, td, pd)
    assert i_h.tolist() == [0, 0, 89, 89] and i_d.tolist() == [0, 0, 89, 89]
    assert i_p.tolist() == [0, 0, 179, 179]


@pytest.mark.parametrize("phi_d", [1.0131 * math.pi, 1.2617 * math.pi, 1.5028 * math.pi, 1.9937 * math.pi])
def test_phi_d_in_pi_to_2pi_is_folded_not_clamped(files, phi_d):
    """phi_d in (pi, 2 pi) reads the bin of phi_d - pi (reciprocity), not bin 179 or a blend of
    179 and 0 (the known pitfall); the swapped pair reads the same bin and value."""
    theta_h, theta_d = torch.tensor([0.3], dtype=torch.float64), torch.tensor([0.4], dtype=torch.float64)
    zero = torch.zeros(1, dtype=torch.float64)
    expected_bin = int((phi_d - math.pi) / math.pi * 180)
    assert bin_indices(0.3, 0.4, phi_d)[2] == expected_bin != 179
    assert flat_index(0.3, 0.4, phi_d) == flat_index(0.3, 0.4, phi_d - math.pi)
    wi, wo = from_rusinkiewicz(theta_h, zero, theta_d, torch.tensor([phi_d], dtype=torch.float64))
    _, _, _, computed = to_rusinkiewicz(wi, wo)
    assert computed.item() < 0  # atan2 reports it as phi_d - 2 pi
    folded = from_rusinkiewicz(theta_h, zero, theta_d, torch.tensor([phi_d - math.pi], dtype=torch.float64))
    assert direction_bins(wi, wo) == direction_bins(*folded) == direction_bins(wo, wi)
    assert direction_bins(wi, wo) % 180 == expected_bin
    material = load_merl(files["ggx"])
    assert torch.equal(material.evaluate(wi, wo), material.evaluate(wo, wi))
    assert torch.equal(material.evaluate(wi, wo), material.evaluate(*folded))


def test_invalid_bins_are_masked_out(tmp_path, centres):
    table = np.full((3, *DIMS), 0.5)
    table[:, :, 60:, :] = -1.0  # theta_d >= 60°: unmeasured
    table[1, 10, 10, 10] = -1.0  # one channel missing makes the bin invalid
    material = load_merl(write_merl(tmp_path / "holes.binary", table))
    assert material.metadata["invalid_bins"] == 90 * 30 * 180 + 1
    wi, wo = centres
    bins = np.arange(N_BINS)
    invalid = (bins // 180) % 90 >= 60
    invalid[(10 * 90 + 10) * 180 + 10] = True
    f = material.evaluate(wi, wo)
    assert (f[torch.from_numpy(invalid)] == 0).all()
    swi, swo, sf = material.samples(3000, seed=2)
    assert len(swi) == 3000 and material.valid(swi, swo).all() and (sf == 0.5).all()
    _, _, theta_d, _ = to_rusinkiewicz(swi, swo)
    assert theta_d.max() < math.radians(60) + 1e-9
    assert torch.equal(sf, material.samples(3000, seed=2)[2])


def test_samples_are_isotropic_rusinkiewicz_uniform(files):
    material = load_merl(files["ggx"])
    wi, wo, f = material.samples(1000, seed=0)
    _, phi_h, _, _ = to_rusinkiewicz(wi, wo)
    assert phi_h.abs().max() < 1e-6 and (wi[:, 2] > 0).all() and (wo[:, 2] > 0).all()
    assert torch.equal(f, material.evaluate(wi, wo)) and (f > 0).all()


# -- broken files -------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def merl_bytes(files):
    return files["lambertian"].read_bytes()


def _corrupt(content: bytes, at: int, value: bytes) -> bytes:
    return content[:at] + value + content[at + len(value):]


BROKEN = {
    "empty": (lambda c: b"", "too short"),
    "dims": (lambda c: struct.pack("<3i", 90, 90, 360) + c[12:], r"dimensions must be \(90, 90, 180\)"),
    "truncated": (lambda c: c[:-8], "truncated"),
    "header only": (lambda c: c[:12], "truncated"),
    "trailing bytes": (lambda c: c + b"\0" * 8, "trailing bytes"),
    "nan": (lambda c: _corrupt(c, 12 + 8 * (N_BINS + 7), struct.pack("<d", float("nan"))),
            r"non-finite value\(s\), first in channel G at bin \(theta_h 0, theta_d 0, phi_d 7\)"),
    "inf": (lambda c: _corrupt(c, 12, struct.pack("<d", float("-inf"))), "non-finite"),
    # issue 26, case 8: finite in float64, inf in the float32 the models compute in
    "beyond float32": (lambda c: _corrupt(c, 12 + 8 * (2 * N_BINS + 3), struct.pack("<d", 1e300)),
                       r"1 value\(s\) beyond float32's range .* first in channel B at bin \(theta_h 0, theta_d 0, phi_d 3\)"),
}


@pytest.mark.parametrize("case", list(BROKEN))
def test_broken_files_raise_data_error(tmp_path, merl_bytes, case):
    make, message = BROKEN[case]
    path = tmp_path / "broken.binary"
    path.write_bytes(make(merl_bytes))
    with pytest.raises(MERLError, match=message) as info:
        load_merl(path)
    assert isinstance(info.value, DataError) and str(info.value).startswith(str(path))


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        read_merl(tmp_path / "none.binary")
