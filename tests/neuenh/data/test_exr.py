"""EXR images, captures (one material per texel; ``neuenh.data.capture``) and per-texel parameter
images (``neuenh.data.param_images``).

Captures are rendered here from an analytical spatially varying GGX (``captures.render_capture``), so
every value read back is compared with the model evaluated independently, texel by texel.
"""

import json
import shutil

import numpy as np
import pytest
import torch

from neuenh.data.errors import DataError
from captures import capture_directions, render_capture
from neuenh.data.capture import read_capture
from neuenh.data.exr import read_exr_channels, write_exr_channels, write_rgb_exr
from neuenh.data.formats import CAPTURE_JSON, detect_format
from neuenh.data.param_images import parameter_channels, parameter_images, read_parameter_exr, write_parameter_exr
from neuenh.data.measured import TableMaterial, load_measured
from neuenh.data.samples import sample_materials
from neuenh.models import get_model

H, W, IMAGES = 8, 8, 20


def ggx_maps(h=H, w=W, seed=0) -> dict[str, np.ndarray]:
    """Smoothly varying GGX parameters, plus noise so no two texels are alike."""
    rng = np.random.default_rng(seed)
    y, x = np.meshgrid(np.linspace(0, 1, h), np.linspace(0, 1, w), indexing="ij")
    return {
        "normal": 0.15 * np.stack([x - 0.5, y - 0.5], axis=-1),
        "t_theta": 0.5 * (x - y)[..., None],
        "rho_d": np.stack([0.1 + 0.6 * x, 0.2 + 0.3 * y, 0.3 * np.ones_like(x)], axis=-1),
        "rho_s": rng.uniform(0.2, 0.9, (h, w, 3)),
        "alpha_x": (0.08 + 0.4 * x)[..., None],
        "alpha_y": (0.08 + 0.4 * y)[..., None],
        "f0": rng.uniform(0.04, 0.9, (h, w, 1)),
    }


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A float32 and a half capture of the same material and directions."""
    folder = tmp_path_factory.mktemp("capture")
    maps, directions = ggx_maps(), capture_directions(IMAGES, seed=3)
    render_capture(folder / "float", maps, directions, name="tile")
    render_capture(folder / "half", maps, directions, half=True)
    return folder, maps, directions


def expected(maps, directions, row, col) -> np.ndarray:
    """f_r (IMAGES, 3) float64 of texel (row, col): GGX evaluated on its own."""
    params = {k: torch.as_tensor(v[row, col], dtype=torch.float64) for k, v in maps.items()}
    wi = torch.tensor([d[0] for d in directions], dtype=torch.float64)
    wo = torch.tensor([d[1] for d in directions], dtype=torch.float64)
    return get_model("ggx").evaluate(wi, wo, params).numpy()


# -- reading what was rendered ---------------------------------------------------------------
@pytest.mark.parametrize("precision, dtype", [("float", np.float32), ("half", np.float16)])
def test_read_back_equals_the_rendered_values(rendered, precision, dtype):
    folder, maps, directions = rendered
    capture = read_capture(folder / precision)
    assert capture.shape == (H, W) and capture.images == IMAGES and capture.image_shape == (H, W)
    assert capture.metadata["pixel_types"] == [np.dtype(dtype).name]
    for row, col in [(0, 0), (3, 5), (7, 7), (6, 1)]:
        want = expected(maps, directions, row, col).astype(dtype).astype(np.float32)
        got = capture.texel(row, col).table.f_r.numpy()
        np.testing.assert_allclose(got, want, rtol=1e-6 if precision == "float" else 2e-3, atol=0)


def test_texel_is_a_table_material_with_the_listed_directions(rendered):
    folder, _, directions = rendered
    capture = read_capture(folder / "float")
    texel = capture.texel(2, 5)
    assert isinstance(texel, TableMaterial) and texel.name == "tile[2,5]" and len(texel) == IMAGES
    assert texel.metadata["texel"] == [2, 5] and texel.metadata["source"] == "exr_capture"
    np.testing.assert_allclose(texel.table.wi.numpy(), np.array([d[0] for d in directions]), rtol=1e-6)
    np.testing.assert_allclose(texel.table.wo.numpy(), np.array([d[1] for d in directions]), rtol=1e-6)
    wi, wo, f = texel.samples(1000, seed=0)  # a table: its rows, all of them
    assert len(f) == IMAGES and torch.equal(f, texel.table.f_r)
    samples = sample_materials(capture.materials(), 5, seed=1)
    assert len(samples.names) == H * W == len(set(samples.names)) and len(samples) == 5 * H * W


def test_regions_and_strides(rendered):
    folder, _, _ = rendered
    full = read_capture(folder / "float")
    materials = full.materials(region=(1, 2, 6, 8), stride=2)
    assert [m.metadata["texel"] for m in materials[:4]] == [[1, 2], [1, 4], [1, 6], [3, 2]]
    assert [m.metadata["grid"] for m in materials[:4]] == [[0, 0], [0, 1], [0, 2], [1, 0]]
    assert len(materials) == 3 * 3
    part = read_capture(folder / "float", region=(1, 2, 6, 8), stride=2)  # reads only those texels
    assert part.shape == (3, 3) and part.values.nbytes == IMAGES * 9 * 12
    assert torch.equal(part.texel(5, 6).table.f_r, full.texel(5, 6).table.f_r)
    with pytest.raises(IndexError, match="texel .2, 2. was not read"):
        part.texel(2, 2)
    with pytest.raises(IndexError, match="outside the 8x8 image"):
        full.texel(8, 0)
    with pytest.raises(ValueError, match="not inside the 8x8 image"):
        full.materials(region=(0, 0, 9, 4))


def test_f_r_cos_captures_are_divided_by_cos_theta_i(tmp_path, rendered):
    _, maps, directions = rendered
    render_capture(tmp_path, maps, directions, quantity="f_r_cos")
    capture = read_capture(tmp_path / CAPTURE_JSON)  # the JSON path works as well as the folder
    want = expected(maps, directions, 4, 4)
    np.testing.assert_allclose(capture.texel(4, 4).table.f_r.numpy(), want, rtol=1e-5)


# -- parameter images ------------------------------------------------------------------------
def test_the_format_is_told_by_content_alone(rendered, tmp_path):
    """``detect_format``, the one sniffer: a capture's folder and its JSON (renamed), an EXR image
    (renamed), never by the name; a measured-material reader refuses them by name of their kind."""
    folder, maps, _ = rendered
    disguised_json = tmp_path / "capture.csv"
    disguised_json.write_text((folder / "float" / CAPTURE_JSON).read_text())
    disguised_exr = tmp_path / "image.npz"
    shutil.copy(folder / "float" / "0000.exr", disguised_exr)
    assert [detect_format(p) for p in (folder / "float", disguised_json, disguised_exr)] == ["capture", "capture", "exr"]
    write_parameter_exr(tmp_path / "params.bin", maps)
    assert detect_format(tmp_path / "params.bin") == "exr"
    with pytest.raises(DataError, match="an OpenEXR image, not a measured material file"):
        load_measured(disguised_exr)
    with pytest.raises(DataError, match="not a regular file .*without the capture.json"):
        detect_format(tmp_path)


def test_parameter_channels_are_named_per_component():
    assert parameter_channels("alpha_x", 1) == ["alpha_x"]
    assert parameter_channels("rho_d", 3) == ["rho_d.R", "rho_d.G", "rho_d.B"]
    assert parameter_channels("normal", 2) == ["normal.0", "normal.1"]
    assert parameter_channels("latent", 3) == ["latent.0", "latent.1", "latent.2"]


@pytest.mark.parametrize("half", [False, True], ids=["float", "half"])
def test_parameter_exr_round_trip(tmp_path, half):
    params = ggx_maps(5, 7)
    params["latent"] = np.random.default_rng(1).normal(size=(5, 7, 27))
    path = write_parameter_exr(tmp_path / "params.exr", params, metadata={"model": "ggx", "state": "0" * 11},
                               half=half)
    channels, _ = read_exr_channels(path)
    assert {"rho_d.R", "rho_s.B", "alpha_x", "normal.1", "latent.0", "latent.26"} <= set(channels)
    image = read_parameter_exr(path)
    assert list(image.params) == list(params) and image.shape == (5, 7)
    assert image.metadata == {"model": "ggx", "state": "0" * 11}
    dtype = np.float16 if half else np.float32
    for name, values in params.items():
        want = values.reshape(5, 7, -1).astype(dtype).astype(np.float32)
        np.testing.assert_array_equal(image.params[name], want)


def test_parameter_exr_without_the_header_is_grouped_by_channel_name(tmp_path):
    rng = np.random.default_rng(0)
    names = ["rho_d.B", "rho_d.R", "rho_d.G", "latent.10", "latent.2", "f0"] + [f"latent.{k}" for k in (0, 1)]
    channels = {n: rng.random((3, 4)) for n in names}
    write_exr_channels(tmp_path / "plain.exr", channels)
    image = read_parameter_exr(tmp_path / "plain.exr")
    assert image.params["rho_d"].shape == (3, 4, 3) and image.params["f0"].shape == (3, 4, 1)
    np.testing.assert_array_equal(image.params["rho_d"][..., 0], channels["rho_d.R"].astype(np.float32))
    order = [channels[f"latent.{k}"] for k in (0, 1, 2, 10)]
    np.testing.assert_array_equal(image.params["latent"], np.stack(order, -1).astype(np.float32))


def test_fitted_texels_written_back_as_images(tmp_path, rendered):
    from neuenh.fit import PlainLBFGS, fit_materials

    folder, _, _ = rendered
    capture = read_capture(folder / "float")
    materials = capture.materials(region=(0, 0, 4, 4), stride=2)
    model = get_model("ggx")
    result = fit_materials(model, sample_materials(materials, IMAGES, 0), PlainLBFGS(iterations=5))
    images = parameter_images(result.materials, [m.metadata["grid"] for m in materials], (2, 2))
    write_parameter_exr(tmp_path / "fit.exr", images, metadata={"model": "ggx"})
    back = read_parameter_exr(tmp_path / "fit.exr")
    values = result.materials.values()
    np.testing.assert_array_equal(back.params["rho_d"][1, 0], values["rho_d"][2].detach().numpy())
    np.testing.assert_array_equal(back.params["latent"][0, 1], result.materials.latent[1].detach().numpy())
    holes = parameter_images({"f0": torch.ones(1, 1)}, [(1, 1)], (2, 2))["f0"]
    assert np.isnan(holes[0, 0, 0]) and holes[1, 1, 0] == 1


# -- bad input -------------------------------------------------------------------------------
def _spec(folder):
    return json.loads((folder / CAPTURE_JSON).read_text())


def _edit(folder, change):
    spec = _spec(folder)
    change(spec)
    (folder / CAPTURE_JSON).write_text(json.dumps(spec))


def _nan_pixel(folder):
    rgb = np.ones((H, W, 3), np.float32)
    rgb[2, 3, 1] = np.nan
    write_rgb_exr(folder / "0001.exr", rgb)


def _truncate(folder):
    data = (folder / "0002.exr").read_bytes()
    (folder / "0002.exr").write_bytes(data[: len(data) // 2])


BAD = {
    "missing-json": (lambda f: (f / CAPTURE_JSON).unlink(), "a folder without capture.json"),
    "not-json": (lambda f: (f / CAPTURE_JSON).write_text("{images: ["), "capture.json: not valid JSON"),
    "missing-image": (lambda f: (f / "0004.exr").unlink(), r"images.4: .*0004.exr is listed but missing"),
    "no-images": (lambda f: _edit(f, lambda s: s.update(images=[])), "images: List should have at least 1 item"),
    "unknown-key": (lambda f: _edit(f, lambda s: s.update(lights=1)), "lights: Extra inputs are not permitted"),
    "non-unit": (lambda f: _edit(f, lambda s: s["images"][3].update(wo=[0, 0, 2])),
                 r"images.3 \(0003.exr\): wo must be a unit vector, its norm is 2"),
    "below-horizon": (lambda f: _edit(f, lambda s: s["images"][0].update(wi=[0, 0.6, -0.8])),
                      r"images.0 \(0000.exr\): wi must be above the surface"),
    "other-size": (lambda f: write_rgb_exr(f / "0005.exr", np.ones((H, W + 1, 3))),
                   r"0005.exr: image size 9x8 .width x height. differs from 0000.exr's 8x8"),
    "nan-pixel": (_nan_pixel, r"0001.exr: 1 pixel\(s\) with NaN or infinite values, first at \(row 2, col 3\) channel G"),
    "negative": (lambda f: write_rgb_exr(f / "0001.exr", -np.ones((H, W, 3))), r"0001.exr: negative pixel value -1"),
    "no-rgb": (lambda f: write_exr_channels(f / "0001.exr", {"Y": np.ones((H, W))}),
               r"0001.exr: lacks channel\(s\) \['R', 'G', 'B'\]"),
    "garbage": (lambda f: (f / "0002.exr").write_bytes(b"not an exr at all" * 20), "0002.exr: not an OpenEXR image"),
    "truncated": (_truncate, "0002.exr: not a readable OpenEXR image"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_captures_raise_data_error_naming_the_file(tmp_path, rendered, capfd, case):
    folder = tmp_path / "cap"
    shutil.copytree(rendered[0] / "float", folder)
    make, match = BAD[case]
    make(folder)
    capfd.readouterr()
    with pytest.raises(DataError, match=match) as info:
        read_capture(folder)
    assert str(folder) in str(info.value)
    printed = capfd.readouterr()
    assert printed.out == printed.err == ""  # the OpenEXR library's own diagnostics are captured


def test_negative_pixels_may_be_clipped(tmp_path, rendered):
    folder = tmp_path / "cap"
    shutil.copytree(rendered[0] / "float", folder)
    rgb = np.full((H, W, 3), 0.5, np.float32)
    rgb[0, 0] = -0.01
    write_rgb_exr(folder / "0001.exr", rgb)
    _edit(folder, lambda s: s.update(negative="clip"))
    capture = read_capture(folder)
    assert capture.texel(0, 0).table.f_r[1].tolist() == [0.0, 0.0, 0.0]
    assert capture.texel(0, 1).table.f_r[1].tolist() == [0.5, 0.5, 0.5]


def test_missing_capture_path(tmp_path):
    with pytest.raises(DataError, match="no such file or folder"):
        read_capture(tmp_path / "nowhere")
