"""The model bundle: what a trained (or initial) enhancement state is, on disk and on the wire.

A bundle directory holds

* ``model.json``: model name, positions, state, module choices, whether alternative terms are
  offered (and every position's choices by name), latent size, parameter specs, training config,
  provenance and metrics;
* ``weights.safetensors``: the neural modules' weights (keys ``<position>.layers.<i>.weight``);
* ``materials.safetensors``: per-material parameters (raw analytical values, latent and any
  per-material corrections of module weights: ``MaterialTable.tensors``), the material names (and
  each material's fit capacity, when recorded) in its metadata. Optional: a shipped model may carry none.
* ``rungs.safetensors``: optional, the *rungs* of the search that made the model — every committed
  round's winner (the latest round of each state), cheaper models on the way to this one — their
  module weights (keys ``<k>.<position>.layers.<i>.weight``) and their training materials' latent
  codes (``<k>.latent_codes``, where new fits start; bundles written before stop 57 kept their mean
  alone, ``<k>.latent_mean``, read as one code); ``model.json`` lists them (round, state, validation
  loss, weights, parameters per material).
* ``encoder.safetensors``: optional, the model's *encoder* (``neuenh.encoder.MaterialEncoder``):
  measurements of a material -> its parameters, the start of its fit; ``model.json``'s ``encoder``
  holds its description and training record. A bundle without one fits from the usual starts.

Loading never unpickles: safetensors and JSON only. Every file is written atomically
(``neuenh.files``: temporary file, fsync, 0644, rename) and ``model.json`` last, so a directory with a ``model.json`` is complete.
``to_bytes``/``from_bytes`` pack the same content into one safetensors blob for transport.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load as st_load
from safetensors.torch import load_file, save, save_file

from .encoder import MaterialEncoder
from .files import atomic_write, atomic_write_digest
from .materials import MaterialTable
from .model import BRDFModel
from .models import get_model
from .modules import ModuleConfig

FORMAT = "neuenh-bundle"
VERSION = 1
MODEL_JSON, WEIGHTS, MATERIALS = "model.json", "weights.safetensors", "materials.safetensors"
RUNGS = "rungs.safetensors"
ENCODER = "encoder.safetensors"


class BundleError(ValueError):
    """A bundle that cannot be read: names the file and what is wrong."""


@dataclass(frozen=True, eq=False)
class Rung:
    """One committed round's winner of the search that made a bundle: a model of the same family,
    usually cheaper. ``model``'s module weights are that round's; ``latent_codes`` (k, latent_dim)
    its training materials' latent codes (``MaterialTable.latent_codes``; None when no module reads
    the latent): what a fit with this rung starts from, as a bundle's materials are for its model."""

    round: int
    val_loss: float
    model: BRDFModel
    latent_codes: torch.Tensor | None = None

    def trained(self) -> MaterialTable | None:
        """``latent_codes`` as a fit's ``trained`` table (``neuenh.fit``: their mean and the codes that
        fit a material best start its fit), or None."""
        if self.latent_codes is None or not self.model.uses_latent:
            return None
        codes = self.latent_codes.float()
        return MaterialTable(self.model.specs, [f"code {i}" for i in range(len(codes))], self.model.latent_dim,
                             latent=codes)

    @property
    def state(self) -> str:
        return self.model.state

    def describe(self) -> dict[str, Any]:
        return {"round": self.round, "state": self.state, "formula": self.model.describe(),
                "val_loss": self.val_loss, "n_weights": self.model.n_weights(),
                "params_per_material": self.model.n_material_params()}

    @classmethod
    def of(cls, round_index: int, val_loss: float, bundle: "Bundle") -> "Rung":
        """The rung of a round's committed bundle."""
        return cls(round_index, float(val_loss), copy.deepcopy(bundle.model), training_codes(bundle))


@dataclass
class Bundle:
    model: BRDFModel
    materials: MaterialTable | None = None
    training: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    rungs: list[Rung] = field(default_factory=list)  # cheapest (first committed) to latest
    encoder: MaterialEncoder | None = None  # amortised starts (neuenh.encoder), if trained

    @classmethod
    def initial(
        cls,
        model_name: str,
        material_names: list[str] | tuple[str, ...],
        module_config: ModuleConfig = ModuleConfig(),
        latent_dim: int = 27,
        alternatives: bool = False,
    ) -> "Bundle":
        """The all-zero analytical model with every material at the paper's initial values."""
        model = get_model(model_name, module_config=module_config, latent_dim=latent_dim, alternatives=alternatives)
        return cls(model, MaterialTable(model.specs, material_names, latent_dim))

    # -- description -------------------------------------------------------------------------
    def describe(self) -> dict[str, Any]:
        m = self.model
        return {
            "format": FORMAT,
            "version": VERSION,
            "model": m.name,
            "positions": list(m.positions),
            "state": m.state,
            "formula": m.describe(),
            "module_config": m.module_config.to_json(),
            "alternatives": m.has_alternatives,
            "choices": {p: list(m.choices(p)) for p in m.positions},  # by digit, for people
            "latent_dim": m.latent_dim,
            "n_weights": m.n_weights(),
            "params_per_material": m.n_material_params(),
            "param_specs": [
                {"name": s.name, "width": s.width, "low": s.low, "high": s.high, "scale": s.scale, "init": s.init}
                for s in m.specs
            ],
            "materials": list(self.materials.names) if self.materials is not None else [],
            "rungs": [r.describe() for r in self.rungs],
            **({"encoder": self.encoder.describe()} if self.encoder is not None else {}),
            "training": self.training,
            "provenance": self.provenance,
            "metrics": self.metrics,
        }

    # -- disk --------------------------------------------------------------------------------
    def save(self, directory: str | os.PathLike) -> Path:
        """Write the bundle's files, each atomically, ``model.json`` last with the SHA-256 of the
        other two: a save killed half-way (new weights beside the old ``model.json``) is refused
        by ``load`` with an error naming the file, never loaded as a mix of two models."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        digests = {WEIGHTS: atomic_write_digest(directory / WEIGHTS, lambda p: save_file(_weights(self.model), p))}
        if self.materials is not None:
            meta = self.materials.metadata()
            digests[MATERIALS] = atomic_write_digest(directory / MATERIALS,
                                                     lambda p: save_file(self.materials.tensors(), p, metadata=meta))
        elif (directory / MATERIALS).exists():
            (directory / MATERIALS).unlink()
        if self.rungs:
            digests[RUNGS] = atomic_write_digest(directory / RUNGS, lambda p: save_file(_rung_tensors(self.rungs), p))
        elif (directory / RUNGS).exists():
            (directory / RUNGS).unlink()
        if self.encoder is not None:
            digests[ENCODER] = atomic_write_digest(directory / ENCODER, lambda p: save_file(self.encoder.tensors(), p))
        elif (directory / ENCODER).exists():
            (directory / ENCODER).unlink()
        text = json.dumps({**self.describe(), "digests": digests}, indent=2, sort_keys=False) + "\n"
        atomic_write(directory / MODEL_JSON, text)
        return directory

    @classmethod
    def load(cls, directory: str | os.PathLike) -> "Bundle":
        directory = Path(directory)
        meta_path = directory / MODEL_JSON
        if not meta_path.is_file():
            raise BundleError(f"{directory}: not a model bundle (no {MODEL_JSON})")
        try:
            meta = json.loads(meta_path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise BundleError(f"{meta_path}: not valid JSON ({exc})") from None
        for name, digest in (meta.get("digests") or {}).items():  # bundles saved before digests have none
            if name not in (WEIGHTS, MATERIALS, RUNGS, ENCODER):
                raise BundleError(f"{meta_path}: digests name an unknown file {name!r}")
            path = directory / name
            if path.is_file() and _sha256(path) != digest:  # a missing one is named by its reader below
                raise BundleError(f"{path}: does not match {MODEL_JSON} (changed since, or left by another "
                                  "save); save the bundle again")
        weights = _read_safetensors(directory / WEIGHTS)
        materials = None
        if (directory / MATERIALS).exists():
            materials = _read_materials(directory / MATERIALS)
        rungs = _read_safetensors(directory / RUNGS) if meta.get("rungs") else {}
        encoder = _read_safetensors(directory / ENCODER) if meta.get("encoder") else None
        return cls._assemble(meta, weights, materials, str(directory), rungs, encoder)

    # -- wire --------------------------------------------------------------------------------
    def to_bytes(self) -> bytes:
        tensors = {f"neural.{k}": v for k, v in _weights(self.model).items()}
        meta = {"model.json": json.dumps(self.describe())}
        if self.materials is not None:
            tensors.update({f"material.{k}": v for k, v in self.materials.tensors().items()})
            meta.update(self.materials.metadata())
        tensors.update({f"rung.{k}": v for k, v in _rung_tensors(self.rungs).items()})
        if self.encoder is not None:
            tensors.update({f"encoder.{k}": v for k, v in self.encoder.tensors().items()})
        return save(tensors, metadata=meta)

    @classmethod
    def from_bytes(cls, blob: bytes) -> "Bundle":
        meta = blob_metadata(blob)
        tensors = st_load(blob)
        weights = {k[len("neural."):]: v for k, v in tensors.items() if k.startswith("neural.")}
        materials = None
        if "names" in meta:
            mt = {k[len("material."):]: v for k, v in tensors.items() if k.startswith("material.")}
            materials = (mt, meta)
        rungs = {k[len("rung."):]: v for k, v in tensors.items() if k.startswith("rung.")}
        description = json.loads(meta["model.json"])
        encoder = ({k[len("encoder."):]: v for k, v in tensors.items() if k.startswith("encoder.")}
                   if description.get("encoder") else None)
        return cls._assemble(description, weights, materials, "<bytes>", rungs, encoder)

    @classmethod
    def _assemble(cls, meta: dict, weights: dict, materials, where: str,
                  rung_tensors: dict[str, torch.Tensor] | None = None,
                  encoder_tensors: dict[str, torch.Tensor] | None = None) -> "Bundle":
        if meta.get("format") != FORMAT:
            raise BundleError(f"{where}: not a {FORMAT} (format {meta.get('format')!r})")
        if meta.get("version") != VERSION:
            raise BundleError(f"{where}: bundle version {meta.get('version')} is not supported ({VERSION})")
        def build(state: str) -> BRDFModel:
            return get_model(
                meta["model"],
                state=state,
                module_config=ModuleConfig.from_json(meta["module_config"]),
                latent_dim=int(meta["latent_dim"]),
                alternatives=bool(meta.get("alternatives", False)),  # bundles before alternatives: none
            )

        try:
            model = build(meta["state"])
        except (KeyError, ValueError, TypeError) as exc:
            raise BundleError(f"{where}: {exc}") from None
        saved_specs = [(p["name"], p["width"], p["low"], p["high"], p["scale"]) for p in meta["param_specs"]]
        current = [(s.name, s.width, s.low, s.high, s.scale) for s in model.specs]
        if saved_specs != current:
            raise BundleError(
                f"{where}: parameter specs differ from this version's {model.name} "
                f"(saved {saved_specs}, current {current})"
            )
        _load_weights(model, weights, where)
        rungs = []
        for k, entry in enumerate(meta.get("rungs") or []):
            what = f"{where} rung {k}"
            try:
                rung_model = build(entry["state"])
            except (KeyError, ValueError, TypeError) as exc:
                raise BundleError(f"{what}: {exc}") from None
            prefix = f"{k}."
            own = {n[len(prefix):]: v for n, v in (rung_tensors or {}).items() if n.startswith(prefix)}
            codes = own.pop("latent_codes", None)
            if "latent_mean" in own:  # written before stop 57: the codes' mean alone
                codes = own.pop("latent_mean").reshape(1, -1)
            _load_weights(rung_model, own, what)
            if codes is not None and (codes.ndim != 2 or codes.shape[1] != rung_model.latent_dim):
                raise BundleError(f"{what}: latent codes of shape {tuple(codes.shape)}, expected (k, "
                                  f"{rung_model.latent_dim})")
            rungs.append(Rung(int(entry["round"]), float(entry["val_loss"]), rung_model, codes))
        table = None
        if materials is not None:
            tensors, material_meta = materials
            try:
                table = MaterialTable.from_tensors(model.specs, json.loads(material_meta["names"]), tensors, material_meta)
                for i in range(len(table)):
                    model.corrected_weights(table.as_params(i).corrections)  # keys and shapes of this model's
            except (ValueError, KeyError, TypeError) as exc:
                raise BundleError(f"{where}: {exc}") from None
        encoder = None
        if encoder_tensors is not None:
            try:
                encoder = MaterialEncoder.from_tensors(model.specs, meta["encoder"], encoder_tensors)
            except ValueError as exc:
                raise BundleError(f"{where} encoder: {exc}") from None
        return cls(model, table, meta.get("training", {}), meta.get("provenance", {}), meta.get("metrics", {}), rungs,
                   encoder)


def blob_metadata(blob: bytes) -> dict[str, str]:
    """The string metadata of an in-memory safetensors blob (its header: an 8-byte little-endian
    length, then JSON whose ``__metadata__`` holds it)."""
    header_len = int.from_bytes(blob[:8], "little")
    return json.loads(blob[8 : 8 + header_len]).get("__metadata__", {})


def _weights(model: BRDFModel) -> dict[str, torch.Tensor]:
    return {k: v.detach().contiguous() for k, v in model.neural.state_dict().items()}


def _load_weights(model: BRDFModel, weights: dict[str, torch.Tensor], where: str) -> None:
    expected = set(_weights(model))
    if set(weights) != expected:
        raise BundleError(
            f"{where}: weights do not match state {model.state} "
            f"(missing {sorted(expected - set(weights))}, unexpected {sorted(set(weights) - expected)})"
        )
    try:
        model.neural.load_state_dict(weights, strict=True)
    except RuntimeError as exc:
        raise BundleError(f"{where}: {exc}") from None


def _rung_tensors(rungs: list[Rung]) -> dict[str, torch.Tensor]:
    out = {}
    for k, rung in enumerate(rungs):
        out.update({f"{k}.{name}": v for name, v in _weights(rung.model).items()})
        if rung.latent_codes is not None:
            out[f"{k}.latent_codes"] = rung.latent_codes.detach().float().contiguous()
    return out


def training_codes(bundle: Bundle) -> torch.Tensor | None:
    """(k, latent_dim) the latent codes of ``bundle``'s training materials, or None when its model
    reads no latent or it holds no materials."""
    if not bundle.model.uses_latent or bundle.materials is None or not bundle.materials.coded():
        return None
    return bundle.materials.latent_codes().clone()


def _read_safetensors(path: Path) -> dict[str, torch.Tensor]:
    if not path.is_file():
        raise BundleError(f"{path}: missing")
    try:
        return load_file(path)
    except Exception as exc:  # safetensors raises its own error types for corrupt files
        raise BundleError(f"{path}: not a readable safetensors file ({exc})") from None


def _read_materials(path: Path) -> tuple[dict[str, torch.Tensor], dict[str, str]]:
    """The tensors and string metadata of a materials file (``MaterialTable.tensors``, ``.metadata``)."""
    from safetensors import safe_open

    tensors = _read_safetensors(path)
    with safe_open(path, framework="pt") as f:
        meta = f.metadata() or {}
    if "names" not in meta:
        raise BundleError(f"{path}: material names missing from the metadata")
    return tensors, meta


def _sha256(path: Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()
