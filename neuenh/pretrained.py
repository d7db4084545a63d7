"""Models by name: analytical models of the registry, models shipped with neuenh, bundle folders.

Shipped models are bundles committed under ``models/<name>/`` at the root of the source tree (the
enhanced GGX trained by ``examples/reference.yaml`` is ``models/enhanced-ggx``). A wheel carries that
folder as the package data ``neuenh/shipped_models/`` (pyproject.toml maps it there); a checkout or an
editable install reads ``models/`` beside the package. A folder named by ``NEUENH_MODELS_DIR`` comes
first: its bundles win over shipped ones of the same name.

Naming the models (``shipped_models``, ``bundle_path``) reads folders only; loading one imports torch
(``neuenh fit --help`` lists them without it).
"""

from __future__ import annotations

import dataclasses
import os
import stat
from pathlib import Path
from typing import TYPE_CHECKING

from .files import existing
from .models import available_models, get_model

if TYPE_CHECKING:
    from .checkpoint import Rung
    from .encoder import MaterialEncoder
    from .materials import MaterialTable
    from .model import BRDFModel

__all__ = ["bundle_path", "load_model", "rungs", "shipped_models"]


_PACKAGE = Path(__file__).resolve().parent


def _shipped_dir() -> Path | None:
    """This installation's shipped models: a wheel's package data, else a source tree's ``models/``
    (only in a source tree: beside an installed package, ``models/`` is someone else's folder)."""
    installed = _PACKAGE / "shipped_models"
    if installed.is_dir():
        return installed
    source_tree = _PACKAGE.parent
    return source_tree / "models" if (source_tree / "pyproject.toml").is_file() else None


def _models_dirs() -> list[Path]:
    dirs = [Path(os.environ["NEUENH_MODELS_DIR"])] if os.environ.get("NEUENH_MODELS_DIR") else []
    shipped = _shipped_dir()
    return dirs + ([shipped] if shipped is not None else [])


def shipped_models() -> dict[str, Path]:
    """Name -> bundle folder of every shipped model (a folder holding a ``model.json``)."""
    found: dict[str, Path] = {}
    for root in reversed(_models_dirs()):  # NEUENH_MODELS_DIR wins on a shared name
        if root.is_dir():
            found.update({p.name: p for p in sorted(root.iterdir()) if (p / "model.json").is_file()})
    return dict(sorted(found.items()))


def bundle_path(spec: str) -> Path | None:
    """The bundle folder ``spec`` names: itself if it is a folder, else a shipped model's, else None
    (a name no file system can hold, too long or with a NUL, is no folder)."""
    status = existing(spec)
    return Path(spec) if status is not None and stat.S_ISDIR(status.st_mode) else shipped_models().get(spec)


def load_model(spec: str, what: str = "model") -> tuple[BRDFModel, MaterialTable | None]:
    """The model ``spec`` names and its training materials (``None`` for an analytical model):
    a bundle folder if ``spec`` is one, else a shipped model, else an analytical model. The
    training materials give new fits a starting latent code (``neuenh.fit``). ``what`` names
    ``spec`` in the error (e.g. the command-line flag)."""
    model, trained, _ = load_for_fitting(spec, what)
    return model, trained


def load_for_fitting(spec: str, what: str = "model") -> tuple[BRDFModel, MaterialTable | None,
                                                               MaterialEncoder | None]:
    """``load_model``'s model and training materials, and the bundle's encoder (``neuenh.encoder``:
    one more start of its latent fits; None without one or for an analytical model): everything a fit
    starts from, from one read of the bundle."""
    from .checkpoint import Bundle

    path = bundle_path(spec)
    if path is not None:
        bundle = Bundle.load(path)
        return bundle.model, bundle.materials, bundle.encoder
    if spec in available_models():
        return get_model(spec), None, None
    raise ValueError(f"{what} {spec!r} is neither an analytical model ({', '.join(available_models())}), "
                     f"a shipped model ({', '.join(shipped_models()) or 'none found'}) nor a bundle folder")


def rungs(spec: str) -> list[Rung]:
    """The rungs of a shipped model or bundle folder: every committed round's winner of the search
    that made it (the latest round of each state), first committed first, the model itself last,
    each with the training codes its fits start from (``Rung.trained``). A bundle saved without its
    search's rungs has one: itself (round -1, its recorded val loss)."""
    from .checkpoint import Bundle, Rung, training_codes

    path = bundle_path(spec)
    if path is None:
        raise ValueError(f"{spec!r} is neither a shipped model ({', '.join(shipped_models()) or 'none found'}) "
                         "nor a bundle folder")
    bundle = Bundle.load(path)
    own = training_codes(bundle)
    if not bundle.rungs:
        return [Rung(-1, float(bundle.metrics.get("val_loss", float("nan"))), bundle.model, own)]
    last = bundle.rungs[-1]
    if last.state == bundle.model.state and own is not None:
        # The model itself: its fits start from the bundle's own training codes, as ``neuenh fit``'s do
        # (the same codes in a bundle written since stop 57; before, its rungs kept their mean alone).
        return [*bundle.rungs[:-1], dataclasses.replace(last, latent_codes=own)]
    return bundle.rungs
