"""Per-material NBRDF networks exported (``neuenh.export.nbrdf``, ``neuenh.export.export_nbrdf``).

1. The network's inputs computed from the vectors (``network_inputs``, what every format runs) equal
   the Rusinkiewicz angles' (``neuenh.data.nbrdf.network_input``: acos, atan2, the phi_d fold) derived
   independently in 40-digit arithmetic — in-plane pairs where phi_d is exactly pi, the half vector
   at the normal and theta_d = 0 included.
2. Every format's artifact, run in its runtime (the adapters of ``test_equals_specialized``), equals the
   network in float64 within ``float32_bounds``' arithmetic bound, is finite and >= 0, and is exactly 0
   below either horizon — for a random network and, with ../shared, two published MERL networks (a
   mirror-like metal's dynamic range, a diffuse one).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuenh.export import export_nbrdf
from neuenh.export.nbrdf import brdf, folded_network, network_inputs
from neuenh.ops import NUMPY, TORCH, BatchVec3, count_flops
from neuenh.study.nbrdf_fit import NBRDFNetwork
from data_files import NBRDF_WEIGHTS, shared
from float32_bounds import assert_within, function_error, measure
from test_equals_specialized import adapter  # noqa: F401  (the fixture: every format in its runtime)

U64 = 2.0**-53


def random_network(seed: int = 3) -> NBRDFNetwork:
    net = NBRDFNetwork(seed=seed)
    with torch.no_grad():
        for layer in net.layers:
            if isinstance(layer, torch.nn.Linear):
                layer.bias.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(seed))
    return net


def published_network(name: str) -> NBRDFNetwork:
    """A published MERL network (``../shared``)."""
    from neuenh.data.nbrdf import nbrdf_material

    return NBRDFNetwork.from_published(nbrdf_material(shared(NBRDF_WEIGHTS), name).weights)


def unit(w: np.ndarray) -> np.ndarray:
    return w / np.linalg.norm(w, axis=-1, keepdims=True)


def directions(rng, n: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """Float64 pairs: uniform on the sphere (a quarter below a horizon), ``n // 2`` near the mirror
    direction, grazing ones, in-plane ones (phi_d exactly 0 or pi), wi = wo (theta_d = 0), the
    normal itself (theta_h = 0) and wo = -wi (no half vector: wo into the surface)."""
    wi = unit(rng.normal(size=(n, 3)))
    wo = unit(rng.normal(size=(n, 3)))
    wi[: n // 2, 2], wo[: n // 2, 2] = np.abs(wi[: n // 2, 2]), np.abs(wo[: n // 2, 2])
    near_i = unit(rng.normal(size=(n // 2, 3)) * [1, 1, 0.2] + [0, 0, 1])
    near_o = unit(near_i * [-1, -1, 1] + rng.normal(scale=0.02, size=near_i.shape))
    t = np.linspace(-1.55, 1.55, 63)
    plane_i = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], -1)
    plane_o = plane_i[::-1] * [0.8, 0, 1]
    grazing = unit(np.stack([np.cos(t), np.sin(t), np.full_like(t, 1e-3)], -1))
    z, tilted = np.array([[0.0, 0.0, 1.0]]), unit(np.array([[0.3, 0.2, 0.9]]))
    return (np.vstack([wi, near_i, plane_i, unit(plane_o), grazing, plane_i, z, tilted]),
            np.vstack([wo, near_o, unit(plane_o), plane_i, grazing[::-1], plane_i, z, -tilted]))


# -- 1. the inputs, against the angles in 40 digits ---------------------------------------------------
def inputs_from_angles(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """``neuenh.data.nbrdf.network_input``'s formula (its always-zero second input left out) in mpmath:
    theta_h, phi_h of the half vector, d = R_y(-theta_h) R_z(-phi_h) wi, phi_d = atan2 folded into [0, pi)."""
    import mpmath as mp

    mp.mp.dps = 40
    out = []
    def unit_mp(w):  # the float64 input, made exactly unit (the formula is for unit vectors)
        w = [mp.mpf(float(v)) for v in w]
        norm = mp.sqrt(sum(v * v for v in w))
        return [v / norm for v in w]

    for a, b in zip(wi, wo):
        a, b = unit_mp(a), unit_mp(b)
        h = [x + y for x, y in zip(a, b)]
        norm = mp.sqrt(sum(v * v for v in h))
        h = [v / norm for v in h]
        theta_h, phi_h = mp.acos(h[2]), mp.atan2(h[1], h[0])
        x = mp.cos(phi_h) * a[0] + mp.sin(phi_h) * a[1]
        y = -mp.sin(phi_h) * a[0] + mp.cos(phi_h) * a[1]
        dx = mp.cos(theta_h) * x - mp.sin(theta_h) * a[2]
        dz = mp.sin(theta_h) * x + mp.cos(theta_h) * a[2]
        theta_d, phi_d = mp.acos(max(min(dz, 1), -1)), mp.atan2(y, dx)
        phi_d = phi_d + mp.pi if phi_d < 0 else phi_d - mp.pi if phi_d >= mp.pi else phi_d
        out.append([mp.sin(theta_h), mp.cos(theta_h), mp.sin(theta_d) * mp.cos(phi_d),
                    mp.sin(theta_d) * mp.sin(phi_d), mp.cos(theta_d)])
    return np.array(out, dtype=np.float64)


@pytest.mark.parametrize("xp", [TORCH, NUMPY], ids=lambda xp: xp.name)
def test_the_inputs_from_vectors_equal_the_angles_in_40_digits(xp):
    """Within float64 rounding amplified by phi_h's condition (its error is ~u / sin theta_h, and it
    turns d by that angle): 64 u (1 + 1 / sin theta_h) per component."""
    rng = np.random.default_rng(0)
    wi, wo = directions(rng, n=512)
    keep = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    wi, wo = wi[keep], wo[keep]
    to = (lambda a: BatchVec3(torch.as_tensor(a))) if xp is TORCH else BatchVec3
    got = np.hstack([np.asarray(v, dtype=np.float64) for v in network_inputs(xp, to(wi), to(wo))])
    want = inputs_from_angles(wi, wo)
    sin_h = want[:, :1]
    bound = 64 * U64 * (1 + 1 / np.maximum(sin_h, 1e-300))
    assert (np.abs(got - want) <= bound).all(), np.abs(got - want).max(0)
    in_plane = (wi[:, 1] == 0) & (wo[:, 1] == 0) & (sin_h[:, 0] > 0)
    assert in_plane.sum() > 100 and (got[in_plane, 3] == 0).all()  # phi_d folded to 0 (from pi where d_x < 0) ...
    assert (got[in_plane, 2] >= 0).all()  # ... so d_x keeps the sign of cos 0


# -- 2. every format in its runtime ----------------------------------------------------------------------
NETWORKS = {"random": random_network, "chrome": lambda: published_network("chrome"),
            "white_diffuse_bball": lambda: published_network("white-diffuse-bball")}


def float64_network(net: NBRDFNetwork):
    """f_r (n, 3) numpy of ``net`` by the exported formula on the ``TORCH`` vocabulary, at the precision
    of the directions it is given (float64 weights for float64 directions)."""
    def evaluate(wi: torch.Tensor, wo: torch.Tensor) -> np.ndarray:
        network = folded_network(net).to(wi.dtype)
        a, b = BatchVec3(wi), BatchVec3(wo)
        value = brdf(TORCH, a, b, lambda inputs: network(torch.cat(inputs, dim=-1)))
        above = (wi[:, 2:3] > 0) & (wo[:, 2:3] > 0)
        return torch.where(above, value.clamp_min(0.0), 0.0).numpy()

    return evaluate


@pytest.mark.parametrize("network", NETWORKS)
def test_every_format_equals_the_network_within_float32_rounding(adapter, network, tmp_path):
    adapter, runtime = adapter
    net = NETWORKS[network]()
    wi, wo = (w.astype(np.float32) for w in directions(np.random.default_rng(1)))
    files = export_nbrdf({network: net}, adapter.name, tmp_path)
    [path] = [p for p in files if p.suffix == adapter.suffix]
    [got] = adapter.run(runtime, [path], [(wi, wo)])

    evaluate = float64_network(net)
    with torch.no_grad():
        measured = measure(evaluate, evaluate, torch.as_tensor(wi), torch.as_tensor(wo))
        e_fn = 0.0 if adapter.functions is None else function_error(
            evaluate, torch.as_tensor(wi), torch.as_tensor(wo), measured, adapter.functions)
    n_ops = count_flops(lambda xp, a, b: network_inputs(xp, a, b)) + folded_network(net).flops + 6 + adapter.extra_ops
    bound = measured.bound(n_ops, adapter.factor, e_fn)
    assert np.isfinite(got).all() and (got >= 0).all()
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    assert below.sum() > 1000 and (got[below] == 0).all()
    assert_within(got, measured.truth, bound, f"{adapter.name}, {network}")
    assert measured.truth[~below].max() > 0  # a material that is not black


def test_the_rung_and_the_export_are_one_network():
    """A scene plan's NBRDF parameters (``NBRDFNetwork.state``) load back as the same network, and the
    rung's own evaluation (angles in float64, the network in float32) equals the exported formula in
    float64 within the a-priori bound of its float32 rounding (Higham 2002, Sec. 3.1): the features
    rounded once, each layer's products and sums within (fan-in + 2) u (|W| |h| + |b|) plus what
    reaches it, then exp and the subtraction of 1."""
    net = random_network()
    again = NBRDFNetwork.from_state(net.state())
    assert all(torch.equal(a, b) for a, b in zip(net.state_dict().values(), again.state_dict().values()))
    wi, wo = (torch.as_tensor(w) for w in directions(np.random.default_rng(2), n=1024))
    keep = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    wi, wo = wi[keep], wo[keep]
    rung = again.evaluate(wi, wo).double().numpy()  # float64 directions: the rung rounds its features once
    exported = float64_network(net)(wi, wo)

    u = 2.0**-24
    h = torch.cat(network_inputs(TORCH, BatchVec3(wi), BatchVec3(wo)), dim=-1)
    error = u * h.abs()
    layers = folded_network(net).to(torch.float64).layers
    for i, (weight, bias) in enumerate(layers):
        magnitude = h.abs() @ weight.abs().t() + bias.abs()
        error = error @ weight.abs().t() + (weight.shape[1] + 2) * u * magnitude
        h = torch.addmm(bias, h, weight.t())
        h = h.clamp_min(0.0) if i < len(layers) - 1 else h  # ReLU: 1-Lipschitz, exact
    bound = (torch.exp(h) * (torch.expm1(error) + 4 * u)).numpy()  # f = exp(o) - 1: exp's and the subtraction's rounding
    assert (np.abs(rung - exported) <= bound).all(), np.abs(rung - exported).max()
    with pytest.raises(ValueError, match="not the weights of an NBRDF network"):
        NBRDFNetwork.from_state({**net.state(), "layers.2.weight": [0.0] * 5})


def test_the_sampling_lobe_follows_the_networks_highlight():
    """``sampling_lobe`` reads a sharp lobe and a high specular share off a mirror-like metal, a wide
    lobe and a low share off a diffuse material, and something between off a metallic paint."""
    from neuenh.export.nbrdf import sampling_lobe

    chrome, paint, diffuse = (sampling_lobe(published_network(name))
                              for name in ("chrome", "gold-metallic-paint", "white-diffuse-bball"))
    assert chrome[0] < 0.02 < paint[0] < diffuse[0]
    assert chrome[1] == 0.9 and diffuse[1] < 0.5
    for alpha, p_spec in (chrome, paint, diffuse, sampling_lobe(random_network())):
        assert 1e-3 <= alpha <= 1.0 and 0.1 <= p_spec <= 0.9
