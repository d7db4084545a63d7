"""Data sources of a job spec, and their materialisation into training data.

A ``DataSource`` is one entry of a job spec's ``data:`` list (DESIGN §4), a pydantic model
discriminated by ``source``. ``materialise`` turns a list of them into contiguous float32
``TrainingData`` with a seeded per-material train/validation split.
"""

from __future__ import annotations

from typing import Annotated, Literal, Sequence, Union

from pydantic import BaseModel, ConfigDict, Field

from ..train import TrainingData
from .samples import Samples, sample_materials
from .synthetic import ZOO_FAMILIES, synthetic_ggx, synthetic_zoo


class _Source(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    samples: int = Field(20_000, ge=1, description="measurements per material")
    seed: int = 0


class SyntheticZoo(_Source):
    """Materials plain GGX cannot represent (neuenh.data.synthetic.synthetic_zoo)."""

    source: Literal["synthetic_zoo"]
    materials: int = Field(32, ge=1)
    families: list[str] | None = None

    def model_post_init(self, _context) -> None:
        unknown = [f for f in self.families or () if f not in ZOO_FAMILIES]
        if unknown:
            raise ValueError(f"unknown zoo families {unknown}; available: {list(ZOO_FAMILIES)}")

    def build(self) -> Samples:
        families = tuple(self.families) if self.families else None
        return sample_materials(synthetic_zoo(self.materials, self.seed, families), self.samples, self.seed)


class SyntheticGGX(_Source):
    """The paper's anisotropic GGX materials with multiplicative N(1, noise) noise."""

    source: Literal["synthetic_ggx"]
    materials: int = Field(100, ge=1)
    noise: float = Field(0.1, ge=0.0)

    def build(self) -> Samples:
        return sample_materials(synthetic_ggx(self.materials, self.seed, self.noise), self.samples, self.seed)


DataSource = Annotated[Union[SyntheticZoo, SyntheticGGX], Field(discriminator="source")]


def materialise(sources: Sequence[SyntheticZoo | SyntheticGGX], val_fraction: float, seed: int) -> TrainingData:
    """All sources' samples, concatenated, split per material into training and validation."""
    if not sources:
        raise ValueError("a job needs at least one data source")
    samples = Samples.concat([s.build() for s in sources])
    if len(set(samples.names)) != len(samples.names):
        duplicates = sorted({n for n in samples.names if samples.names.count(n) > 1})
        raise ValueError(f"material names occur in more than one source: {duplicates[:5]}")
    return TrainingData(*samples.split(val_fraction, seed))
