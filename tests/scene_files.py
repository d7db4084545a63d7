"""Scene files the scene tests write themselves: measurement tables of materials whose best rung is
known, and a scene over them (``neuenh.scene``)."""

from __future__ import annotations

from pathlib import Path

from neuenh.data.directions import sample_directions
from neuenh.data.synthetic import synthetic_ggx, synthetic_zoo
from neuenh.data.table import write_table


def write_material(path: Path, material, n: int = 1600, seed: int = 0) -> Path:
    wi, wo = sample_directions(n, seed=seed, near_mirror=0.3)
    return write_table(path, wi, wo, material.evaluate(wi, wo))


def write_tables(folder: Path) -> Path:
    """gloss.npz: plain anisotropic GGX without noise; retro.npz and sheen.npz: zoo materials."""
    [gloss] = synthetic_ggx(1, seed=3, noise_sigma=0.0)
    write_material(folder / "gloss.npz", gloss)
    write_material(folder / "retro.npz", synthetic_zoo(1, seed=1, families=("retro",))[0])
    write_material(folder / "sheen.npz", synthetic_zoo(1, seed=2, families=("sheen",))[0])
    return folder


def scene(folder: Path, **changes) -> dict:
    """GGX's own material (weight 3) and a retro-reflective one, on the ladder [ggx, nbrdf]."""
    return {"name": "known", "materials": [{"path": "gloss.npz", "weight": 3.0}, {"path": "retro.npz"}],
            "ladder": ["ggx", "nbrdf"], "tolerance": {"metric": "log_l1", "relative": 0.1},
            "fit": {"samples": 1000, "test_samples": 500, "seed": 0, "epochs": 100}, **changes}


def runaway(folder: Path, epochs: int = 1000, copies: int = 60) -> dict:
    """A plan that runs until it is cancelled: NBRDF fitted for ``epochs`` to ``copies`` copies of
    gloss.npz (``write_tables``). One copy at 1,000 epochs fits in about a second once the plan's
    process is up, so a plan of one may end before a test has cancelled it (one did, in CI)."""
    return scene(folder, ladder=["nbrdf"], fit={"samples": 300, "test_samples": 200, "epochs": epochs},
                 materials=[{"path": str(folder / "gloss.npz"), "name": f"gloss{i}"} for i in range(copies)])


def write_module_bundle(folder: Path):
    """A bundle of GGX with one module (invE, random weights) saved at ``folder``: a model with modules
    for a ladder's ``{model: folder, capacity: C}``. Returns its model."""
    from neuenh.checkpoint import Bundle

    bundle = Bundle.initial("ggx", ["a"])
    bundle.model = bundle.model.enhance("00000100000", seed=1)
    bundle.save(folder)
    return bundle.model
