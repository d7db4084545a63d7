"""RGL ``.bsdf``: the tensor_file container, the evaluator, and its errors.

Layers: (1) the container against an independent writer; (2) closed forms on tiny generated
materials (uniform / linear VNDF, bilinear rgb: every step of the evaluator is exact there);
(3) the reference values of the real materials; (4) every kind of broken file is a DataError.
"""

import math
import struct
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import torch

from neuenh.data.errors import DataError
from neuenh.data.rgl import RGLMaterial, TensorFileError, load_rgl, parse_tensor_file, read_tensor_file
from neuenh.data.directions import to_rusinkiewicz

from data_files import (
    RGL_DIR, RGL_MATERIALS, RGL_REFERENCE, aliased_tensor_file_bytes, hemisphere, shared, tensor_file_bytes,
    tiny_rgl_fields, write_tensor_file,
)


def tiny(tmp_path, name="tiny.bsdf", **kwargs) -> RGLMaterial:
    return load_rgl(write_tensor_file(tmp_path / name, tiny_rgl_fields(**kwargs)))


def pairs(theta_i, phi_i, theta_m, phi_m):
    """Directions with the given spherical angles of wi and of the half vector (wo above only)."""
    def sph(t, p):
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)

    wi, m = sph(np.asarray(theta_i), np.asarray(phi_i)), sph(np.asarray(theta_m), np.asarray(phi_m))
    wo = 2 * np.sum(wi * m, -1, keepdims=True) * m - wi
    keep = wo[:, 2] > 0.05
    return wi[keep], wo[keep], m[keep]


def random_angles(n, seed):
    rng = np.random.default_rng(seed)
    return (rng.uniform(0.0, 1.4, n), rng.uniform(-math.pi, math.pi, n),
            rng.uniform(0.05, 0.8, n), rng.uniform(-math.pi, math.pi, n))


def unit_square(wi, m):
    """The evaluator's (u_x, u_y) of the half vector, isotropic, in float64."""
    theta_m = np.arccos(np.clip(m[:, 2], -1, 1))
    dphi = np.arctan2(m[:, 1], m[:, 0]) - np.arctan2(wi[:, 1], wi[:, 0])
    u_y = (dphi + math.pi) / (2 * math.pi)
    return np.sqrt(2 * theta_m / math.pi), u_y - np.floor(u_y)


# -- 1. the container --------------------------------------------------------------------------
def test_container_round_trips_every_dtype(tmp_path):
    rng = np.random.default_rng(0)
    fields = {f"f{code}_{dt}": (rng.standard_normal((2, 3)) * 50).astype(dt)
              for code, dt in enumerate(["u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f2", "f4", "f8"], 1)}
    fields["scalarish"] = np.arange(1, dtype=np.float32)
    fields["empty"] = np.zeros((0, 4), dtype=np.float64)
    fields["cube"] = rng.random((2, 3, 4)).astype(np.float32)
    got = read_tensor_file(write_tensor_file(tmp_path / "all.tf", fields))
    assert list(got) == list(fields)
    for name, a in fields.items():
        assert got[name].dtype == a.dtype and got[name].shape == a.shape
        np.testing.assert_array_equal(got[name], a)


def test_real_file_structure():
    fields = read_tensor_file(shared(RGL_DIR / "paper_white_rgb.bsdf"))
    assert fields["vndf"].shape == (1, 8, 128, 128) and fields["rgb"].shape == (1, 8, 3, 32, 32)
    material = load_rgl(RGL_DIR / "paper_white_rgb.bsdf")
    assert material.name == "paper_white_rgb" and material.isotropic
    assert "paper" in material.metadata["description"].lower()
    assert material.metadata["source"] == "rgl"


# -- 2. closed forms on tiny materials ---------------------------------------------------------
def test_uniform_vndf_is_the_identity_warp_and_rgb_is_bilinear(tmp_path):
    """A uniform VNDF inverts to u_wm itself; rgb is bilinear in (x, y), so interpolation is exact;
    ndf / (4 sigma) = 2 / (4 · 0.5) = 1."""
    material = tiny(tmp_path)
    wi, wo, m = pairs(*random_angles(500, 1))
    x, y = unit_square(wi, m)
    expected = np.stack([0.1 + x, 0.2 + y, 0.3 + 0.5 * x * y], axis=1)
    np.testing.assert_allclose(material.evaluate_cos(wi, wo), expected, rtol=2e-5, atol=2e-6)


@pytest.mark.parametrize("axis", ["x", "y"])
def test_linear_vndf_inverts_through_its_cdf(tmp_path, axis):
    """Density 1 + t along one axis: the inverse warp is its CDF (t + t²/2) / 1.5 on that axis and
    the identity on the other (trapezoid CDFs and bilinear patches are exact for linear data)."""
    density = (lambda x, y: 1 + x) if axis == "x" else (lambda x, y: 1 + y)
    material = tiny(tmp_path, vndf=density, rgb=lambda c, x, y: (x, y, 0.5 + 0 * x)[c])
    wi, wo, m = pairs(*random_angles(500, 2))
    x, y = unit_square(wi, m)
    cdf = (lambda t: (t + t * t / 2) / 1.5)
    expected = np.stack([cdf(x) if axis == "x" else x, cdf(y) if axis == "y" else y, np.full_like(x, 0.5)], 1)
    np.testing.assert_allclose(material.evaluate_cos(wi, wo), expected, rtol=2e-5, atol=2e-6)


def test_rgb_is_interpolated_linearly_in_theta_i_and_clamped(tmp_path):
    fields = tiny_rgl_fields(n_theta=4)  # theta_i = 0, 0.5, 1.0, 1.5
    fields["rgb"] = np.broadcast_to(np.arange(4, dtype=np.float32)[None, :, None, None, None], fields["rgb"].shape).copy()
    material = load_rgl(write_tensor_file(tmp_path / "theta.bsdf", fields))
    theta_i = np.array([0.0, 0.25, 0.5, 0.9, 1.2, 1.5, 1.52])
    wi, wo, _ = pairs(theta_i, np.zeros(7), np.full(7, 0.01), np.zeros(7))
    assert len(wi) == 7
    expected = np.minimum(theta_i / 0.5, 3.0)
    np.testing.assert_allclose(material.evaluate_cos(wi, wo)[:, 0], expected, rtol=1e-5, atol=1e-6)


def test_ndf_and_sigma_scale_the_value(tmp_path):
    a = tiny(tmp_path, "a.bsdf")
    b = tiny(tmp_path, "b.bsdf", ndf=6.0, sigma=0.25)  # (6 / 1) / (2 / 2) = 6 times larger
    wi, wo, _ = pairs(*random_angles(200, 3))
    np.testing.assert_allclose(b.evaluate_cos(wi, wo), 6 * a.evaluate_cos(wi, wo), rtol=1e-6)


def test_negative_rgb_is_clipped_at_zero(tmp_path):
    material = tiny(tmp_path, rgb=lambda c, x, y: (x - 0.5, -1 + 0 * x, 0.25 + 0 * x)[c])
    wi, wo, m = pairs(*random_angles(300, 4))
    f = material.evaluate_cos(wi, wo)
    x, _ = unit_square(wi, m)
    assert (f[:, 1] == 0).all() and (f[x < 0.49, 0] == 0).all() and (f[x > 0.51, 0] > 0).all()
    np.testing.assert_allclose(f[:, 2], 0.25, rtol=1e-6)


def test_f_r_is_the_cosine_weighted_value_over_cos_theta_o_and_zero_below(tmp_path):
    material = tiny(tmp_path)
    wi, wo, _ = pairs(*random_angles(200, 5))
    f = material.evaluate(torch.from_numpy(wi), torch.from_numpy(wo))
    assert f.dtype == torch.float64 and f.shape == (len(wi), 3)
    np.testing.assert_allclose(f.numpy() * wo[:, 2:3], material.evaluate_cos(wi, wo), rtol=1e-6)
    below = np.array([[0.3, 0.0, -0.1], [0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [1.0, 0.0, 0.0]])
    above = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, -0.1], [0.0, 0.6, 0.0], [0.0, 0.0, 1.0]])
    assert (material.evaluate(below, above) == 0).all() and (material.evaluate_cos(below, above) == 0).all()


def test_batches_do_not_change_values(tmp_path):
    """Pairs are evaluated in chunks; a pair's value does not depend on its batch."""
    material = tiny(tmp_path)
    wi, wo = hemisphere(70_000, 6), hemisphere(70_000, 7)
    whole = material.evaluate_cos(wi, wo)
    np.testing.assert_array_equal(whole[-10:], material.evaluate_cos(wi[-10:], wo[-10:]))
    np.testing.assert_array_equal(whole[:10], material.evaluate_cos(wi[:10], wo[:10]))


def test_samples_are_rusinkiewicz_uniform_isotropic_and_seeded(tmp_path):
    material = tiny(tmp_path)
    wi, wo, f = material.samples(500, seed=3)
    assert wi.shape == wo.shape == f.shape == (500, 3)
    _, phi_h, _, _ = to_rusinkiewicz(wi, wo)
    assert phi_h.abs().max() < 1e-6  # isotropic: phi_h = 0
    assert torch.equal(f, material.evaluate(wi, wo))
    assert torch.equal(f, material.samples(500, seed=3)[2])


# -- 3. the real materials against the reference evaluator ----------------------------------------
@pytest.fixture(scope="module")
def reference():
    with np.load(shared(RGL_REFERENCE)) as z:
        return {k: z[k] for k in z.files}


@pytest.mark.parametrize("name", RGL_MATERIALS)
def test_agrees_with_the_reference_evaluator(reference, name):
    """Relative error <= 1e-3 wherever the reference exceeds 1e-3 of the material's maximum (all
    agree to ~1e-4 at worst, ~1e-7 in the median); exactly zero where the reference is zero."""
    assert "f_r*cos(theta_o)" in str(reference["returns"])
    material = load_rgl(shared(RGL_DIR / f"{name}.bsdf"))
    ref = reference[name]
    got = material.evaluate_cos(reference["wi"], reference["wo"]).astype(np.float64)
    mask = ref > 1e-3 * ref.max()
    rel = np.abs(got - ref)[mask] / ref[mask]
    assert rel.max() <= 1e-3, f"max relative error {rel.max():.3g}"
    np.testing.assert_array_equal(got[ref == 0], 0.0)
    f = material.evaluate(reference["wi"], reference["wo"]).numpy()
    np.testing.assert_allclose(f * reference["wo"][:, 2:3], got, rtol=1e-6, atol=0)


# -- 4. broken files ---------------------------------------------------------------------------
def broken(tmp_path, content: bytes) -> Path:
    path = tmp_path / "broken.bsdf"
    path.write_bytes(content)
    return path


def valid_bytes(**overrides) -> bytes:
    return tensor_file_bytes(tiny_rgl_fields(), overrides=overrides)


def without(name: str) -> bytes:
    fields = tiny_rgl_fields()
    del fields[name]
    return tensor_file_bytes(fields)


def with_field(**changes) -> bytes:
    fields = tiny_rgl_fields()
    fields.update(changes)
    return tensor_file_bytes(fields)


def nan_vndf() -> bytes:
    fields = tiny_rgl_fields()
    fields["vndf"] = fields["vndf"].copy()
    fields["vndf"][0, 1, 2, 3] = np.nan
    return tensor_file_bytes(fields)


BROKEN = {
    "empty": (lambda: b"", "too short"),
    "wrong magic": (lambda: b"tensor_fiLe\0" + valid_bytes()[12:], "bad magic"),
    "wrong version": (lambda: valid_bytes()[:12] + b"\x02\x00" + valid_bytes()[14:], "version 2.0"),
    "truncated header": (lambda: valid_bytes()[:200], "header truncated"),
    "oversized field count": (lambda: valid_bytes()[:14] + struct.pack("<I", 10**9) + valid_bytes()[18:],
                              "claims 1000000000 fields"),
    "offset past the end": (lambda: valid_bytes(vndf={"offset": 10**6}), "'vndf'.*extends past the end"),
    "shape past the end": (lambda: valid_bytes(rgb={"shape": (1, 3, 3, 4, 5)}), "'rgb'.*extends past the end"),
    "impossible shape": (lambda: valid_bytes(rgb={"shape": (1, 3, 3, 4, 10**12)}), "'rgb' has shape .* larger than"),
    "empty but huge": (lambda: valid_bytes(rgb={"shape": (0, 2**40, 2**30)}), "'rgb' has shape .* larger than"),
    "too many dimensions": (lambda: valid_bytes(rgb={"shape": (1,) * 40}), "'rgb' has 40 dimensions"),
    "truncated data": (lambda: valid_bytes()[:-20], "extends past the end"),
    "unknown dtype code": (lambda: valid_bytes(ndf={"code": 12}), "unknown dtype code 12"),
    "invalid dtype code 0": (lambda: valid_bytes(ndf={"code": 0}), "unknown dtype code 0"),
    "missing vndf": (lambda: without("vndf"), r"missing field\(s\) \['vndf'\]"),
    "missing description": (lambda: without("description"), "missing field"),
    "wrong dtype": (lambda: with_field(theta_i=np.linspace(0, 1.5, 3)), "'theta_i' must be float32"),
    "wrong rank": (lambda: with_field(ndf=np.ones(6, dtype=np.float32)), "'ndf' must be float32 with 2"),
    "inconsistent rgb": (lambda: with_field(rgb=np.ones((1, 3, 3, 4, 5), dtype=np.float32)), "rgb must have shape"),
    "inconsistent vndf": (lambda: with_field(vndf=np.ones((1, 2, 4, 5), dtype=np.float32)), "vndf must have shape"),
    "grid too small": (lambda: with_field(sigma=np.ones((1, 6), dtype=np.float32)), "2 x 2 grid"),
    "non-finite": (nan_vndf, "'vndf' has 1 non-finite"),
    "theta_i not increasing": (lambda: with_field(theta_i=np.array([0, 1, 0.5], dtype=np.float32)), "strictly increasing"),
    "zero vndf": (lambda: with_field(vndf=np.zeros((1, 3, 4, 5), dtype=np.float32)), "integrate to zero"),
    # issue 26: a header naming one block for several fields would copy it once per field
    "aliased fields": (lambda: aliased_tensor_file_bytes(400, 4096), r"claim 1638400 bytes in all, more than the 4096"),
    "overlapping fields": (lambda: valid_bytes(ndf={"offset": first_data_offset()}), "fields 'version' and 'ndf' overlap"),
    "data inside the header": (lambda: valid_bytes(version={"offset": 20}), "'version' starts at byte 20, inside the header"),
}


def first_data_offset() -> int:
    """Where the first field's data ('version', whose offset is at byte 30 of the header) begin."""
    return struct.unpack_from("<Q", valid_bytes(), 30)[0]


@pytest.mark.parametrize("case", list(BROKEN))
def test_broken_files_raise_data_error_naming_file_and_problem(tmp_path, case):
    make, message = BROKEN[case]
    path = broken(tmp_path, make())
    with pytest.raises(TensorFileError, match=message) as info:
        load_rgl(path)
    assert isinstance(info.value, DataError) and isinstance(info.value, ValueError)
    assert str(info.value).startswith(str(path))


def test_aliased_fields_are_refused_before_anything_is_copied():
    """Issue 26, case 1: 400 fields naming one 4 MB block took a server from 492 MB to 1,998 MB
    before its 422. Refused from the header alone: what the parser allocates stays far below one
    copy of the block (measured by tracemalloc, which numpy reports its arrays to)."""
    content = aliased_tensor_file_bytes(400, 4 << 20)
    tracemalloc.start()
    try:
        with pytest.raises(TensorFileError, match="fields overlap"):
            parse_tensor_file(content, "aliased.bsdf")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < (4 << 20) // 8, f"the parser allocated {peak} bytes"


def test_duplicate_field_is_an_error(tmp_path):
    content = bytearray(valid_bytes())
    # Rename the field "phi_i" to "sigma" (same length), which already exists.
    at = content.index(b"phi_i")
    content[at:at + 5] = b"sigma"
    with pytest.raises(DataError, match="'sigma' appears twice"):
        load_rgl(broken(tmp_path, bytes(content)))


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        load_rgl(tmp_path / "nope.bsdf")
    with pytest.raises(DataError, match="not a regular file"):
        load_rgl(tmp_path)


def test_anisotropic_symmetry_reduction_is_rejected(tmp_path):
    fields = tiny_rgl_fields()
    n_theta = len(fields["theta_i"])
    fields["phi_i"] = np.linspace(0, math.pi, 4).astype(np.float32)  # half the circle: reduction 2
    for key in ("vndf", "luminance", "rgb"):
        fields[key] = np.repeat(fields[key], 4, axis=0)
    assert fields["vndf"].shape[:2] == (4, n_theta)
    with pytest.raises(DataError, match="symmetry reduction 2"):
        load_rgl(write_tensor_file(tmp_path / "aniso.bsdf", fields))
    fields["phi_i"] = np.linspace(-math.pi, math.pi, 4).astype(np.float32)
    material = load_rgl(write_tensor_file(tmp_path / "aniso.bsdf", fields))
    assert not material.isotropic
    wi, wo, f = material.samples(200, seed=0)
    assert torch.isfinite(f).all() and (f >= 0).all()
