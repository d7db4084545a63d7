"""NBRDF networks as measured materials (Sztrajman, Rainer, Ritschel, Weyrich 2021, "Neural BRDF
Representation and Importance Sampling", CGF 40(6); code MIT).

One small MLP per material, fitted by its authors to a MERL measurement (Matusik et al. 2003), so a
network file stands in for the MERL database. Weights file (``.npz``): ``names`` (the materials),
and per name ``<name>/W1`` (6×H1), ``b1``, ``W2`` (H1×H2), ``b2``, ``W3`` (H2×3), ``b3``
(H1 = H2 = 21 in the published networks).

Evaluation at the Rusinkiewicz angles (theta_h, theta_d, phi_d) of a pair (isotropic, phi_h unused):

    x  = [sin theta_h, 0, cos theta_h, sin theta_d cos phi_d, sin theta_d sin phi_d, cos theta_d]
    h1 = relu(x W1 + b1);  h2 = relu(h1 W2 + b2);  f_r (RGB) = max(exp(h2 W3 + b3) - 1, 0)

in MERL units (f_r without the cosine; the MERL scale factors are already in the networks).
The forward pass runs in float64 on the float32 weights.

**phi_d is folded into [0, pi) before the network** (+pi when negative, -pi when >= pi), the MERL
domain. Swapping ``wi`` and ``wo`` turns phi_d into phi_d ± pi, so the fold makes every material
exactly reciprocal. The raw networks are not (their two halves differ by a few per cent, median
1-6 % depending on the material): they were trained on phi_d over [0, 2 pi) with targets from a
MERL lookup that does not fold phi_d, so only the [0, pi) half saw correctly looked-up targets.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from .errors import DataError
from .merl import as_directions as _as_directions
from .directions import Sampling, to_rusinkiewicz

LAYERS = ("W1", "b1", "W2", "b2", "W3", "b3")


class NBRDFError(DataError):
    """An NBRDF weights file that cannot be read, or a material it does not hold."""


def fold_phi_d(phi_d: torch.Tensor) -> torch.Tensor:
    """phi_d folded into [0, pi) by reciprocity."""
    phi_d = torch.where(phi_d < 0, phi_d + torch.pi, phi_d)
    return torch.where(phi_d >= torch.pi, phi_d - torch.pi, phi_d)


def network_input(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """The networks' 6 inputs (n, 6) of direction pairs: half vector at phi_h = 0, difference vector."""
    theta_h, _, theta_d, phi_d = to_rusinkiewicz(wi, wo)
    phi_d = fold_phi_d(phi_d)
    st = torch.sin(theta_d)
    return torch.stack([torch.sin(theta_h), torch.zeros_like(theta_h), torch.cos(theta_h),
                        st * torch.cos(phi_d), st * torch.sin(phi_d), torch.cos(theta_d)], dim=-1)


@dataclass
class NBRDFMaterial:
    """One NBRDF network as a continuous, isotropic material."""

    name: str
    weights: dict[str, np.ndarray] = field(repr=False)
    metadata: dict = field(default_factory=dict)
    isotropic: bool = True

    def __post_init__(self) -> None:
        self._t = {k: torch.from_numpy(np.asarray(self.weights[k], dtype=np.float64)) for k in LAYERS}

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """The network on inputs ``x`` (n, 6): f_r (n, 3), float64."""
        t = self._t
        h = torch.relu(x @ t["W1"] + t["b1"])
        h = torch.relu(h @ t["W2"] + t["b2"])
        return torch.expm1(h @ t["W3"] + t["b3"]).clamp_min(0.0)

    def evaluate(self, wi, wo) -> torch.Tensor:
        """f_r (n, 3) float64 without the cosine factor; 0 where either direction is not above."""
        wi, wo = _as_directions(wi, wo)
        above = (wi[:, 2:3] > 0) & (wo[:, 2:3] > 0)
        f = self.forward(network_input(wi, wo))
        return torch.where(above, f, torch.zeros_like(f))

    def samples(self, n: int, seed: int, sampling: Sampling = Sampling()
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``n`` pairs drawn as ``sampling`` says (by default Rusinkiewicz-uniform at phi_h = 0)
        and their f_r."""
        wi, wo = sampling.directions(n, seed, self.isotropic)
        return wi, wo, self.evaluate(wi, wo)


def is_nbrdf_keys(keys) -> bool:
    """Whether the member names of an ``.npz`` look like an NBRDF weights file."""
    keys = set(keys)
    return "names" in keys and any(k.endswith("/W1") for k in keys)


def _open(path: Path):
    if not path.exists():
        raise NBRDFError(f"{path}: no such file")
    if not path.is_file():
        raise NBRDFError(f"{path}: not a regular file")
    try:
        return np.load(path, allow_pickle=False)
    except Exception as exc:  # noqa: BLE001 - numpy/zipfile raise many types for a corrupt archive
        raise NBRDFError(f"{path}: not a readable .npz file ({type(exc).__name__}: {exc})") from None


def _get(npz, key: str, path: Path) -> np.ndarray:
    try:
        a = npz[key]
    except KeyError:
        raise NBRDFError(f"{path}: missing array {key!r}") from None
    except Exception as exc:  # noqa: BLE001 - a corrupt member: zlib, zipfile, numpy errors
        raise NBRDFError(f"{path}: array {key!r} cannot be read ({type(exc).__name__}: {exc})") from None
    if not isinstance(a, np.ndarray):  # numpy hands back raw bytes for a member that is no .npy
        raise NBRDFError(f"{path}: member {key!r} is not a .npy array")
    return a


def _names(npz, path: Path) -> tuple[str, ...]:
    names = _get(npz, "names", path)
    if names.ndim != 1 or names.dtype.kind not in "US":
        raise NBRDFError(f"{path}: 'names' must be a 1-D array of strings, got {names.dtype}{list(names.shape)}")
    out = tuple(str(n) for n in names)
    if len(set(out)) != len(out):
        raise NBRDFError(f"{path}: 'names' has duplicates")
    return out


def _weights(npz, name: str, path: Path) -> dict[str, np.ndarray]:
    w = {k: _get(npz, f"{name}/{k}", path) for k in LAYERS}
    for k, a in w.items():
        if a.dtype.kind != "f":
            raise NBRDFError(f"{path}: {name}/{k} must be floating point, got {a.dtype}")
    h1, h2 = (w["W1"].shape[1] if w["W1"].ndim == 2 else -1), (w["W2"].shape[1] if w["W2"].ndim == 2 else -1)
    expected = {"W1": (6, h1), "b1": (h1,), "W2": (h1, h2), "b2": (h2,), "W3": (h2, 3), "b3": (3,)}
    for k, shape in expected.items():
        if w[k].shape != shape or min(shape) < 1:
            raise NBRDFError(f"{path}: {name}/{k} must have shape {shape} (a 6-H1-H2-3 network), "
                             f"got {list(w[k].shape)}")
        if not np.isfinite(w[k]).all():
            raise NBRDFError(f"{path}: {name}/{k} has non-finite values")
    return {k: a.astype(np.float32, copy=False) for k, a in w.items()}


def _material(npz, name: str, path: Path) -> NBRDFMaterial:
    w = _weights(npz, name, path)
    metadata = {"source": "nbrdf", "path": str(path), "network": name,
                "hidden": [int(w["W1"].shape[1]), int(w["W2"].shape[1])], "units": "MERL",
                "reference": "Sztrajman et al. 2021, Neural BRDF Representation and Importance Sampling"}
    return NBRDFMaterial(name, w, metadata)


def nbrdf_names(path: str | os.PathLike) -> tuple[str, ...]:
    """The names of the materials in an NBRDF weights file."""
    path = Path(path)
    with _open(path) as npz:
        return _names(npz, path)


def load_nbrdf(path: str | os.PathLike) -> dict[str, NBRDFMaterial]:
    """Every network of the weights file at ``path``, by material name (in file order)."""
    path = Path(path)
    with _open(path) as npz:
        return {name: _material(npz, name, path) for name in _names(npz, path)}


def nbrdf_material(path: str | os.PathLike, name: str) -> NBRDFMaterial:
    """The network of material ``name`` in the weights file at ``path``."""
    path = Path(path)
    with _open(path) as npz:
        names = _names(npz, path)
        if name not in names:
            shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
            raise NBRDFError(f"{path}: no NBRDF material named {name!r} ({len(names)} available: {shown})")
        return _material(npz, name, path)
