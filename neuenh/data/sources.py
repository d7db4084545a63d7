"""Data sources of a job spec, and their materialisation into training data.

A ``DataSource`` is one entry of a job spec's ``data:`` list (ARCHITECTURE §4), a pydantic model
discriminated by ``source``. ``materialise`` turns a list of them into contiguous float32
``TrainingData`` with a seeded per-material train/validation split.

==================  ==========================================  ==================================
``source``          fields (besides ``samples``, ``seed``)      materials
==================  ==========================================  ==================================
``synthetic_zoo``   ``materials``, ``families``, ``prefix``     closed forms GGX cannot represent
``synthetic_ggx``   ``materials``, ``noise``, ``prefix``        noisy anisotropic GGX (the paper)
``nbrdf``           ``path``, ``materials`` (names; all if      one per NBRDF network (MERL
                    omitted), ``prefix``                        stand-in)
``merl``            ``paths``, ``prefix``                       one per MERL ``.binary``
``rgl``             ``paths``, ``prefix``                       one per RGL ``.bsdf``
``table``           ``paths``, ``prefix``                       one per table (npz or CSV)
``exr_capture``     ``path`` (folder or JSON), ``region``,      one per texel
                    ``stride``, ``prefix``
==================  ==========================================  ==================================

``samples`` is the number of measurements **per material** and ``seed`` seeds them (material
``i`` of a source uses ``seed * 100003 + i``, so adding a material changes no other). ``holdout``
keeps that many of a source's materials out of training (``held_out``): their samples go to
``TrainingData.holdout``, where a search scores candidates by fitting them (``neuenh.selection``). Continuous
sources (synthetic, NBRDF, MERL, RGL) are sampled uniformly in Rusinkiewicz coordinates; tables
and capture texels use their stored measurements — all of them by default (``samples`` omitted),
else a seeded subset of that many rows. Files are read by ``load_measured`` / the capture reader,
which recognise formats by content; a file of the wrong kind (say an RGL file under ``merl``) is
an error. Paths are relative to the current directory. Material names are the files' stems (the
network names for NBRDF, ``<capture>[row,col]`` for texels), with ``prefix`` prepended; they must
be unique across all sources of a job.

The bytes of materialised arrays: ``TrainingData.nbytes``. Checking a spec imports no torch
(``neuenh-client submit`` does it before it sends the job): the readers, the sampling and the
synthetic materials are imported where a source is built.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from typing import TYPE_CHECKING, Callable, Annotated, Literal, Sequence, Union

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from .errors import DataError

if TYPE_CHECKING:
    from .directions import Sampling
    from .samples import Samples, TrainingData

# "near the mirror direction" in degrees (``neuenh.data.directions.MIRROR_DEG``) and the zoo's families
# by name (``neuenh.data.synthetic.ZOO_FAMILIES`` draws them), written here for a spec's check without
# torch; tests/neuenh/data/test_sources.py keeps each equal to its source.
MIRROR_DEG = 10.0
ZOO_FAMILY_NAMES = ("conductor", "two_lobes", "clear_coat", "sheen", "retro", "oren_nayar")

_KIND_LABEL = {"rgl": "an RGL .bsdf (tensor_file)", "merl": "a MERL .binary", "nbrdf": "NBRDF weights",
               "table": "a measurement table", "capture": "an image-based capture", "exr": "an OpenEXR image",
               "dataset": "a materialised training dataset"}


class _Source(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    samples: int = Field(20_000, ge=1, description="measurements per material")
    prefix: str = Field("", description="prepended to every material name (to keep names unique)")
    # below 2^32: material i's seed is seed * 100003 + i, which must fit torch's 64-bit seeds
    seed: int = Field(0, ge=0, lt=2**32)
    holdout: int = Field(0, ge=0, description=(
        "this many of the source's materials (chosen by a permutation seeded with 'seed') are kept out "
        "of training altogether: a search scores candidates by fitting them (search.score: fit)"))

    @model_validator(mode="after")
    def _some_left(self):
        listed = getattr(self, "materials", None)
        count = listed if isinstance(listed, int) else len(listed) if listed else None
        if count is not None and self.holdout >= count:
            raise ValueError(f"holdout ({self.holdout}) must leave at least one of the {count} materials to train on")
        return self

    def _named(self, materials: list) -> list:
        for m in materials:
            m.name = self.prefix + m.name
        return materials

    def strata(self, n_materials: int) -> list[int] | None:
        """The kind of each of the source's ``n_materials`` materials, when they come in kinds a
        held-out set must cover (``held_out``); None: one kind."""
        return None


class _Continuous(_Source):
    """A source of continuous materials, which can draw its pairs anywhere (``Sampling``)."""

    near_mirror: float = Field(0.0, ge=0.0, le=1.0, description=(
        "share of each material's pairs drawn near the mirror direction (half vector within "
        f"{MIRROR_DEG:g} degrees of the normal); the rest Rusinkiewicz-uniform"))
    every_azimuth: bool = Field(False, description=(
        "isotropic materials over every azimuth phi_h too, not only phi_h = 0"))

    @property
    def sampling(self) -> Sampling:
        from .directions import Sampling

        return Sampling(self.near_mirror, self.every_azimuth)

    def load_materials(self) -> list:
        """The source's materials (named, with ``evaluate`` and ``samples``), unsampled."""
        raise NotImplementedError

    def build(self, check: Callable[[], None] | None = None) -> Samples:
        from .samples import sample_materials

        return sample_materials(self.load_materials(), self.samples, self.seed, check=check, sampling=self.sampling)


class SyntheticZoo(_Continuous):
    """Materials plain GGX cannot represent (neuenh.data.synthetic.synthetic_zoo)."""

    source: Literal["synthetic_zoo"]
    materials: int = Field(32, ge=1)
    families: list[str] | None = None

    def model_post_init(self, _context) -> None:
        unknown = [f for f in self.families or () if f not in ZOO_FAMILY_NAMES]
        if unknown:
            raise ValueError(f"unknown zoo families {unknown}; available: {list(ZOO_FAMILY_NAMES)}")

    def load_materials(self) -> list:
        from .synthetic import synthetic_zoo

        families = tuple(self.families) if self.families else None
        return self._named(synthetic_zoo(self.materials, self.seed, families))

    def strata(self, n_materials: int) -> list[int]:
        # synthetic_zoo cycles through the families: material i is of family i mod their count
        return [i % len(self.families or ZOO_FAMILY_NAMES) for i in range(n_materials)]


class SyntheticGGX(_Continuous):
    """The paper's anisotropic GGX materials with multiplicative N(1, noise) noise."""

    source: Literal["synthetic_ggx"]
    materials: int = Field(100, ge=1)
    noise: float = Field(0.1, ge=0.0)

    def load_materials(self) -> list:
        from .synthetic import synthetic_ggx

        return self._named(synthetic_ggx(self.materials, self.seed, self.noise))


# -- measured files --------------------------------------------------------------------------
class _Files(_Source):
    def files(self) -> list[Path]:
        """Every file this source reads (a folder's files, recursively), in a stable order."""
        out: list[Path] = []
        for p in map(Path, getattr(self, "paths", None) or [getattr(self, "path")]):
            out.extend(sorted(f for f in p.rglob("*") if f.is_file()) if p.is_dir() else [p])
        return out

def _paths_field():
    return Field(min_length=1, description="files, relative to the current directory")


def _unique(values: list[str] | None, what: str) -> list[str] | None:
    if values is not None:
        duplicates = sorted({v for v in values if values.count(v) > 1})
        if duplicates:
            raise ValueError(f"{what} listed twice: {duplicates}")
    return values


def _load(path: str, kind: str):
    """``load_measured(path)``, checking that the content is of ``kind``."""
    from .measured import detect_format, load_measured

    found = detect_format(path)
    if found != kind:
        raise DataError(f"{path}: expected {_KIND_LABEL[kind]} for a '{kind}' source, but the file holds "
                        f"{_KIND_LABEL[found]}")
    return load_measured(path)


class NBRDFSource(_Files, _Continuous):
    """Networks of an NBRDF weights file (Sztrajman et al. 2021; a stand-in for MERL)."""

    source: Literal["nbrdf"]
    path: str = Field(min_length=1)
    materials: list[str] | None = Field(None, min_length=1, description="network names; all when omitted")

    @field_validator("materials")
    @classmethod
    def _no_duplicates(cls, v):
        return _unique(v, "NBRDF materials")

    def load_materials(self) -> list:
        from .measured import detect_format
        from .nbrdf import load_nbrdf, nbrdf_material

        found = detect_format(self.path)
        if found != "nbrdf":
            raise DataError(f"{self.path}: expected NBRDF weights for an 'nbrdf' source, but the file holds "
                            f"{_KIND_LABEL[found]}")
        if self.materials is None:
            return self._named(list(load_nbrdf(self.path).values()))
        return self._named([nbrdf_material(self.path, name) for name in self.materials])


class _PathsSource(_Files):
    paths: list[str] = _paths_field()
    _kind = ""

    @field_validator("paths")
    @classmethod
    def _no_duplicates(cls, v):
        return _unique(v, "paths")


class _MeasuredPaths(_PathsSource, _Continuous):
    def load_materials(self) -> list:
        return self._named([_load(p, self._kind) for p in self.paths])


class MERLSource(_MeasuredPaths):
    """MERL ``.binary`` tables (nearest-bin lookup, invalid bins never sampled)."""

    source: Literal["merl"]
    _kind = "merl"


class RGLSource(_MeasuredPaths):
    """EPFL RGL ``.bsdf`` measurements (the paper's validation set)."""

    source: Literal["rgl"]
    _kind = "rgl"


class TableSource(_PathsSource):
    """A user's measurement tables (npz or CSV, neuenh.data.table), one material per file."""

    source: Literal["table"]
    samples: int | None = Field(None, ge=1, description="rows per table; all rows when omitted")
    _kind = "table"

    def build(self, check: Callable[[], None] | None = None) -> Samples:
        from .samples import sample_materials

        materials = self._named([_load(p, self._kind) for p in self.paths])
        return sample_materials(materials, self.samples or max(len(m) for m in materials), self.seed, check=check)


class EXRCaptureSource(_Files):
    """An image-based capture (neuenh.data.capture): one material per texel."""

    source: Literal["exr_capture"]
    path: str = Field(min_length=1, description="the capture folder or its JSON")
    region: tuple[int, int, int, int] | None = Field(
        None, description="(row0, col0, row1, col1), half-open, in image pixels; the whole image when omitted")
    stride: int = Field(1, ge=1, description="every stride-th texel in both directions")
    samples: int | None = Field(None, ge=1, description="images per texel; all when omitted")

    @field_validator("region")
    @classmethod
    def _region(cls, v):
        if v is not None and not (0 <= v[0] < v[2] and 0 <= v[1] < v[3]):
            raise ValueError(f"region (row0, col0, row1, col1) needs 0 <= row0 < row1 and 0 <= col0 < col1, got {v}")
        return v

    def build(self, check: Callable[[], None] | None = None) -> Samples:
        from .capture import read_capture
        from .samples import sample_materials

        capture = read_capture(self.path, self.region, self.stride)
        materials = self._named(capture.materials())
        return sample_materials(materials, self.samples or capture.images, self.seed, check=check)


Source = SyntheticZoo | SyntheticGGX | NBRDFSource | MERLSource | RGLSource | TableSource | EXRCaptureSource
DataSource = Annotated[
    Union[SyntheticZoo, SyntheticGGX, NBRDFSource, MERLSource, RGLSource, TableSource, EXRCaptureSource],
    Field(discriminator="source"),
]


def materialise(sources: Sequence[Source], val_fraction: float, seed: int,
                check: Callable[[], None] | None = None) -> TrainingData:
    """All sources' samples, concatenated, split per material into training and validation.
    ``check`` is called before each material is sampled (it may raise to abandon the work, e.g.
    when the job is cancelled while preparing)."""
    from .samples import Samples, TrainingData

    if not sources:
        raise ValueError("a job needs at least one data source")
    parts = [s.build(check) for s in sources]
    origin: dict[str, int] = {}
    for k, part in enumerate(parts):
        for name in part.names:
            if name in origin:
                where = (f"data[{origin[name]}] ({sources[origin[name]].source}) and data[{k}] ({sources[k].source})"
                         if origin[name] != k else f"data[{k}] ({sources[k].source}) twice")
                raise ValueError(f"material name {name!r} occurs in {where}; names must be unique across "
                                 "sources (set 'prefix' on a source to tell them apart)")
            origin[name] = k
    kept, held = zip(*(_hold_out(source, part) for source, part in zip(sources, parts)))
    held = [h for h in held if h.names]
    samples = Samples.concat(kept)
    return TrainingData(*samples.split(val_fraction, seed), holdout=Samples.concat(held) if held else None)


def held_out(source: Source, n_materials: int) -> list[int]:
    """Indices of the ``source.holdout`` materials (of ``n_materials``) kept out of training, in
    index order: a permutation seeded with the source's seed, taken round-robin over the source's
    ``strata`` (the first of each kind, then the second, ...; with one kind, the permutation's first
    ``holdout``), so a held-out set as large as the number of kinds has one of each — a fit score
    that never sees a kind cannot tell a candidate that fails it (docs/BENCHMARKS.md, issue 23). A
    fixed set: the same source gives the same materials whatever else the job holds."""
    if not source.holdout:
        return []
    if source.holdout >= n_materials:
        raise ValueError(f"a {source.source} source holds out {source.holdout} of its {n_materials} materials; "
                         "at least one must remain to train on")
    import torch

    order = torch.randperm(n_materials, generator=torch.Generator().manual_seed(source.seed)).tolist()
    kinds = source.strata(n_materials) or [0] * n_materials
    earlier: Counter[int] = Counter()  # kind -> how many of it come earlier in the permutation
    turn = {}  # material -> the round of the round-robin that takes it
    for i in order:
        turn[i] = earlier[kinds[i]]
        earlier[kinds[i]] += 1
    return sorted(sorted(order, key=turn.__getitem__)[: source.holdout])  # a stable sort: permutation order within a round


def _hold_out(source: Source, part: Samples) -> tuple[Samples, Samples]:
    """(the materials trained on, the materials held out) of one source's samples."""
    held = held_out(source, len(part.names))
    return part.select([i for i in range(len(part.names)) if i not in held]), part.select(held)


__all__ = ["DataSource", "Source", "SyntheticZoo", "SyntheticGGX", "NBRDFSource", "MERLSource", "RGLSource",
           "TableSource", "EXRCaptureSource", "held_out", "materialise"]
