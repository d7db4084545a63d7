"""PREPARING: materialise a job's training data once, cached in the ArtifactStore by the content
hash of what determines it (the data sources, the split, the code's data version)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Callable

from safetensors.torch import load, save

from neuenh.checkpoint import blob_metadata
from neuenh.data.samples import Samples
from neuenh.data.sources import materialise
from neuenh.data.samples import TrainingData

from .spec import JobSpec

# Bump when sampling or synthetic materials change, so stale cached datasets are not reused.
DATA_VERSION = 1
_FIELDS = ("wi", "wo", "f_r", "material")


def dataset_key(spec: JobSpec) -> str:
    """Content hash of the recipe, including the bytes of every file a source reads (a file
    changed in place must not be served from a stale cache)."""
    recipe = {
        "version": DATA_VERSION,
        "data": [s.model_dump(mode="json") for s in spec.data],
        "files": [[_file_digest(f) for f in s.files()] if hasattr(s, "files") else [] for s in spec.data],
        "val_fraction": spec.train.val_fraction,
        "split_seed": spec.train.seed,
    }
    digest = hashlib.sha256(json.dumps(recipe, sort_keys=True).encode()).hexdigest()
    return f"datasets/{digest}.json"  # the cache index: it names the dataset's content key


def _file_digest(path: Path) -> str:
    """sha256 of a file's content ("missing" when absent: building the dataset reports it)."""
    if not path.is_file():
        return "missing"
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def to_bytes(data: TrainingData) -> bytes:
    parts = {"train": data.train, "val": data.val, **({"holdout": data.holdout} if data.holdout is not None else {})}
    tensors = {f"{part}.{f}": getattr(samples, f).contiguous() for part, samples in parts.items() for f in _FIELDS}
    metadata = {"names": json.dumps(list(data.names))}
    if data.holdout is not None:
        metadata["holdout_names"] = json.dumps(list(data.holdout.names))
    return save(tensors, metadata=metadata)


def from_bytes(blob: bytes) -> TrainingData:
    metadata = blob_metadata(blob)
    names = {"train": tuple(json.loads(metadata["names"]))}
    names["val"] = names["train"]
    if "holdout_names" in metadata:
        names["holdout"] = tuple(json.loads(metadata["holdout_names"]))
    tensors = load(blob)
    parts = {part: Samples(*(tensors[f"{part}.{f}"] for f in _FIELDS), part_names) for part, part_names in names.items()}
    return TrainingData(parts["train"], parts["val"], parts.get("holdout"))


def prepare_dataset(spec: JobSpec, artifacts, check: Callable[[], None] | None = None) -> tuple[TrainingData, str]:
    """The job's data, built or read from the cache; returns it with its (content) artifact key.
    The cache is indexed by the recipe's hash (``dataset_key``); the index names the dataset's
    content key, which ``get`` verifies, so a corrupted cached dataset is an error, never used.
    ``check`` runs before each material is built (see ``materialise``)."""
    index = dataset_key(spec)
    if artifacts.exists(index):
        key = json.loads(artifacts.get(index))["content"]
        return from_bytes(artifacts.get(key)), key  # a content key: get re-hashes the bytes
    data = materialise(spec.data, spec.train.val_fraction, spec.train.seed, check)
    key = artifacts.put_content(to_bytes(data))
    artifacts.put(index, json.dumps({"content": key}).encode())
    return data, key



__all__ = ["dataset_key", "prepare_dataset", "to_bytes", "from_bytes"]
