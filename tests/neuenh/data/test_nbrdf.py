"""NBRDF networks of the MERL materials: loading, the published sanity values, reciprocity, and
the forward pass against a hand-written numpy one."""

import math

import numpy as np
import pytest
import torch

from neuenh.data.errors import DataError
from neuenh.data.nbrdf import NBRDFError, load_nbrdf, nbrdf_material, nbrdf_names
from neuenh.data.directions import to_rusinkiewicz

from data_files import NBRDF_WEIGHTS, hemisphere, nbrdf_weights, shared


@pytest.fixture(scope="module")
def networks():
    return load_nbrdf(shared(NBRDF_WEIGHTS))


def mirror_pairs(theta_h, theta_d, phi_d):
    """wi, wo (float64) at Rusinkiewicz angles with phi_h = 0, written out by hand."""
    theta_h, theta_d, phi_d = (np.asarray(a, dtype=np.float64) for a in (theta_h, theta_d, phi_d))
    d = np.stack([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], 1)
    c, s = np.cos(theta_h), np.sin(theta_h)
    wi = np.stack([c * d[:, 0] + s * d[:, 2], d[:, 1], -s * d[:, 0] + c * d[:, 2]], 1)
    h = np.stack([s, np.zeros_like(s), c], 1)
    wo = 2 * np.sum(wi * h, 1, keepdims=True) * h - wi
    return torch.from_numpy(wi), torch.from_numpy(wo)


def numpy_forward(path, name, wi, wo):
    """The README's network, from the npz, with its own half/difference vectors: h = (wi + wo)/|.|,
    d = wi in the frame (t, b, h) with t the tangent in the plane of h and the normal."""
    with np.load(path) as z:
        w = {k: z[f"{name}/{k}"].astype(np.float64) for k in ("W1", "b1", "W2", "b2", "W3", "b3")}
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    theta_h = np.arccos(np.clip(h[:, 2], -1, 1))
    phi_h = np.arctan2(h[:, 1], h[:, 0])
    t = np.stack([np.cos(theta_h) * np.cos(phi_h), np.cos(theta_h) * np.sin(phi_h), -np.sin(theta_h)], 1)
    b = np.stack([-np.sin(phi_h), np.cos(phi_h), np.zeros_like(phi_h)], 1)
    d = np.stack([np.sum(wi * t, 1), np.sum(wi * b, 1), np.sum(wi * h, 1)], 1)
    theta_d = np.arccos(np.clip(d[:, 2], -1, 1))
    phi_d = np.mod(np.arctan2(d[:, 1], d[:, 0]), math.pi)  # folded into [0, pi)
    x = np.stack([np.sin(theta_h), np.zeros_like(theta_h), np.cos(theta_h),
                  np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d), np.cos(theta_d)], 1)
    h1 = np.maximum(x @ w["W1"] + w["b1"], 0)
    h2 = np.maximum(h1 @ w["W2"] + w["b2"], 0)
    return np.maximum(np.exp(h2 @ w["W3"] + w["b3"]) - 1, 0)


def test_all_hundred_materials_by_name(networks):
    assert len(networks) == 100
    assert list(networks) == list(nbrdf_names(NBRDF_WEIGHTS))
    assert {"chrome", "white-fabric", "alum-bronze", "yellow-plastic"} <= set(networks)
    chrome = nbrdf_material(NBRDF_WEIGHTS, "chrome")
    assert chrome.name == "chrome" and chrome.isotropic and chrome.metadata["source"] == "nbrdf"
    assert chrome.metadata["hidden"] == [21, 21]


def test_chrome_at_normal_half_vector_is_about_500(networks):
    wi, wo = mirror_pairs(np.zeros(3), [0.05, 0.1, 0.2], [0.3, 1.0, 2.0])
    f = networks["chrome"].evaluate(wi, wo)
    assert ((f > 400) & (f < 650)).all(), f


def test_white_fabric_is_nearly_flat_near_0_11(networks):
    """Away from grazing angles the red channel stays near 0.11 (green and blue sit lower, about
    0.084 and 0.061 on average) and no channel varies by more than a factor 2 (5-95 %)."""
    wi, wo, f = networks["white-fabric"].samples(20_000, seed=0)
    f = f[(wi[:, 2] > 0.2) & (wo[:, 2] > 0.2)].numpy()
    assert abs(np.median(f[:, 0]) - 0.11) < 0.015
    q05, q95 = np.quantile(f, [0.05, 0.95], axis=0)
    assert (q95 / q05 < 2.5).all(), (q05, q95)


@pytest.mark.parametrize("name", ["chrome", "white-fabric", "gold-paint", "blue-acrylic", "alum-bronze"])
def test_reciprocity(networks, name):
    wi, wo = torch.from_numpy(hemisphere(3000, 1)), torch.from_numpy(hemisphere(3000, 2))
    material = networks[name]
    torch.testing.assert_close(material.evaluate(wi, wo), material.evaluate(wo, wi), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("name", ["chrome", "white-fabric", "pink-felt", "two-layer-gold"])
def test_forward_matches_a_hand_written_numpy_network(networks, name):
    wi, wo = hemisphere(25, 3), hemisphere(25, 4)
    expected = numpy_forward(NBRDF_WEIGHTS, name, wi, wo)
    got = networks[name].evaluate(torch.from_numpy(wi), torch.from_numpy(wo)).numpy()
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)


def test_zero_below_the_horizon_and_samples(networks):
    material = networks["gold-paint"]
    wi = torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.0, -0.8], [0.6, 0.0, 0.0]], dtype=torch.float64)
    wo = torch.tensor([[0.6, 0.0, -0.8], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    assert (material.evaluate(wi, wo) == 0).all()
    swi, swo, f = material.samples(2000, seed=5)
    _, phi_h, _, _ = to_rusinkiewicz(swi, swo)
    assert phi_h.abs().max() < 1e-6 and (f >= 0).all() and torch.isfinite(f).all()
    assert torch.equal(f, material.evaluate(swi, swo)) and torch.equal(f, material.samples(2000, seed=5)[2])


# -- small generated files and errors ------------------------------------------------------------
def test_generated_weights_file(tmp_path):
    path = tmp_path / "nets.npz"
    np.savez(path, **nbrdf_weights(["a", "b"], seed=1))
    materials = load_nbrdf(path)
    assert list(materials) == ["a", "b"] and materials["a"].metadata["hidden"] == [5, 5]
    wi, wo = hemisphere(10, 0), hemisphere(10, 1)
    np.testing.assert_allclose(materials["b"].evaluate(wi, wo).numpy(), numpy_forward(path, "b", wi, wo), rtol=1e-9)


def _file(tmp_path, arrays):
    path = tmp_path / "nets.npz"
    np.savez(path, **arrays)
    return path


@pytest.mark.parametrize("case, change, message", [
    ("missing array", lambda a: a.pop("a/W2"), "missing array 'a/W2'"),
    ("wrong shape", lambda a: a.update({"a/W1": np.zeros((5, 5), np.float32)}), r"a/W1 must have shape \(6, 5\)"),
    ("inconsistent", lambda a: a.update({"a/b2": np.zeros(4, np.float32)}), r"a/b2 must have shape \(5,\)"),
    ("integer", lambda a: a.update({"a/b3": np.zeros(3, np.int64)}), "must be floating point"),
    ("non-finite", lambda a: a["a/W3"].__setitem__((0, 0), np.inf), "non-finite"),
    ("names", lambda a: a.update({"names": np.zeros(2)}), "'names' must be a 1-D array of strings"),
])
def test_bad_weights_raise_data_error(tmp_path, case, change, message):
    arrays = nbrdf_weights(["a"])
    change(arrays)
    path = _file(tmp_path, arrays)
    with pytest.raises(NBRDFError, match=message) as info:
        load_nbrdf(path)
    assert isinstance(info.value, DataError) and str(info.value).startswith(str(path))


def test_unknown_name_and_unreadable_files(tmp_path):
    path = _file(tmp_path, nbrdf_weights(["a", "b"]))
    with pytest.raises(DataError, match="no NBRDF material named 'chromee' .2 available: a, b."):
        nbrdf_material(path, "chromee")
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(DataError, match="not a readable .npz"):
        load_nbrdf(garbage)
    with pytest.raises(DataError, match="no such file"):
        load_nbrdf(tmp_path / "none.npz")
