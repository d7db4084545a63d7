"""The job spec (ARCHITECTURE §4): what a user submits, validated with a message that names the field.

    model: ggx
    search: {radius: 1, epochs_per_round: 30, max_rounds: 20, max_neural: null, fixed: {},
             complexity_weight: 0.0, min_improvement: 0.0, prune: none, score: val,
             fit_score: {fit_samples: 1000, test_samples: 4000, epochs: 300}}
    module: {hidden: [16, 32, 16]}
    latent_dim: 27
    train: {optimizer: rmsprop, lr: 1.0e-3, batch_size: 100000, val_fraction: 0.1, seed: 0}
    data:
      - {source: synthetic_zoo, materials: 32, samples: 20000, seed: 1}
    resources: {cpus_per_candidate: 1, gpus_per_candidate: 0}
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any, Annotated, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from neuenh.data.sources import DataSource
from neuenh.graph import Graph, ModuleConfig, StateEncoding
from neuenh.models import available_models, get_graph, get_model, models_with_alternatives
from neuenh.search import Constraints

if TYPE_CHECKING:
    from neuenh.checkpoint import Bundle
    from neuenh.model import BRDFModel
    from neuenh.train import FitScoreConfig, TrainConfig

# neuenh.train.Precision, written out so that a spec is checked without torch (``neuenh-client submit``;
# tests/orchestrator/test_spec.py keeps the two equal).
Precision = Literal["float32", "bfloat16"]


def lone_surrogate_path(value: Any, path: str = "") -> str | None:
    """The dotted path of the first string (key or value) in ``value`` holding a lone surrogate,
    or None when every string is valid Unicode."""
    if isinstance(value, str):
        return path if any("\ud800" <= c <= "\udfff" for c in value) else None
    if isinstance(value, dict):
        for key, item in value.items():
            where = f"{path}.{key}" if path else str(key)
            found = lone_surrogate_path(key, where) if isinstance(key, str) else None
            if found is None:
                found = lone_surrogate_path(item, where)
            if found is not None:
                return found
    if isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            found = lone_surrogate_path(item, f"{path}[{i}]")
            if found is not None:
                return found
    return None


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class StopWhen(_Strict):
    """"Enough accuracy for its cost": end the search (STOPPED, reason "stop_when") after a round whose
    winner is good enough, instead of adding modules until nothing helps. Either or both. Both read the
    loss that selects (``search.score``): the validation loss, or the fit score."""

    val_loss_below: float | None = Field(None, gt=0.0, description=(
        "stop once the round's winner has a validation loss at most this"))
    gain_below: float | None = Field(None, gt=0.0, lt=1.0, description=(
        "stop once a round's winner lowers the stay candidate's validation loss by less than this share"))

    @model_validator(mode="after")
    def _some(self) -> "StopWhen":
        if self.val_loss_below is None and self.gain_below is None:
            raise ValueError("give val_loss_below, gain_below or both")
        return self


class FitScoreSpec(_Strict):
    """How each candidate is scored on the held-out materials (``neuenh.selection``)."""

    fit_samples: int = Field(1000, ge=1, description="samples of each held-out material its parameters are fitted to")
    test_samples: int = Field(4000, ge=1, description="of its other samples, at most this many are measured")
    epochs: int = Field(300, ge=1, description=(
        "the fit's epochs (fit.fit_materials), by default the users' fit's: fits of 100 epochs, a third of the price, "
        "ranked a search's rounds otherwise than users' fits of the same materials do (docs/BENCHMARKS.md, 'Stop 60')"))
    capacity: Literal["latent", "auto"] = Field("latent", description=(
        "what each held-out material's fit frees: 'latent', its latent code and analytical parameters; 'auto', "
        "neuenh fit's default, which also frees module corrections where the material's own cross-validation "
        "chooses them (about twice the price; docs/BENCHMARKS.md, 'Stop 62')"))

    def config(self, seed: int) -> FitScoreConfig:
        from neuenh.train import FitScoreConfig

        return FitScoreConfig(self.fit_samples, self.test_samples, self.epochs, seed, self.capacity)


class SearchSpec(_Strict):
    radius: int = Field(1, ge=0, le=4)
    epochs_per_round: int = Field(30, ge=1)
    max_rounds: int = Field(20, ge=1)
    warmup_epochs: int = Field(0, ge=0, description=(
        "train the starting state this many epochs before round 0, so that round 0's candidates grow "
        "from fitted parameters (B_c's trained weights) rather than the initial values, where the "
        "analytical state wins by converging fastest"))
    max_neural: int | None = Field(None, ge=0)
    fixed: dict[str, int] = Field(default_factory=dict, description="position name -> digit it keeps")
    allowed: dict[str, list[int]] = Field(default_factory=dict, description="position name -> digits it may take")
    complexity_weight: float = Field(0.0, ge=0.0, description="score = val_loss + weight x cost (see 'cost')")
    cost: Literal["weights", "time"] = Field("weights", description=(
        "what complexity_weight weighs: 'weights', the state's neural weights / 1000; 'time', its specialized "
        "evaluation cost in units of 100 ns per evaluation, measured once per state on the service's machine "
        "(on the first training material, one thread) and kept in the job's events so a resumed job reuses it"))
    stop_when: StopWhen | None = None
    min_improvement: float = Field(0.0, ge=0.0, lt=1.0, description="relative gain a change must bring over stay")
    score: Literal["val", "fit"] = Field("val", description=(
        "what selects a round's winner (and halving's survivors, and stop_when): 'val', the validation loss "
        "(held-out samples of the training materials); 'fit', the fit score: the materials the data sources "
        "hold out ('holdout'), never trained on, fitted with the candidate's modules frozen on part of their "
        "samples and measured on the rest (neuenh.selection), the way users use a model. Whenever materials "
        "are held out, both are computed and recorded"))
    fit_score: FitScoreSpec = Field(default_factory=FitScoreSpec)
    prune: Literal["none", "halving"] = "none"
    halving_fraction: float = Field(0.34, gt=0.0, lt=1.0, description="share of the epochs before halving")
    polish_epochs: int = Field(0, ge=0, description=(
        "when the search ends (converged or max_rounds), train the final state this many more epochs "
        "with the lr decayed by a cosine to train.lr_final (lr/100 when unset); committed as one last "
        "round whose only candidate is the final state"))


Widths = Annotated[list[Annotated[int, Field(ge=1)]], Field(min_length=1)]


class ModuleSpec(_Strict):
    hidden: Widths = Field(default_factory=lambda: [16, 32, 16], description="hidden layer widths")
    alternatives: list[Widths] = Field(default_factory=list, description="digits 2, 3, ...: other widths")

    def config(self) -> ModuleConfig:
        return ModuleConfig(choices=tuple(tuple(h) for h in (self.hidden, *self.alternatives)))


class TrainSpec(_Strict):
    optimizer: Literal["rmsprop"] = "rmsprop"
    lr: float = Field(1e-3, gt=0.0)
    batch_size: int = Field(100_000, ge=1)
    val_fraction: float = Field(0.1, gt=0.0, lt=1.0)
    seed: int = Field(0, ge=0, lt=2**32, description="seeds the split and every candidate's initialisation")
    lr_final: float | None = Field(None, gt=0.0, description=(
        "unset: a constant lr (the paper); else each candidate's lr follows a cosine from lr down to "
        "lr_final over its epochs, so candidates are compared settled"))
    compile: bool = Field(False, description=(
        "compile each candidate's training step with torch.compile (the workers need a C++ compiler): "
        "steps 2.1-2.5x (batch 4096) and 2.1x (batch 100K) faster after 5-20 s of compiling per batch shape, so "
        "worth it for long candidates (from a few hundred steps; docs/BENCHMARKS.md)"))
    precision: Precision = Field("float32", description=(
        "'bfloat16': each training step's matrix products in bfloat16 (parameters, optimiser and loss stay "
        "float32; validation, fit scores and fits run in float32): on CPUs with bfloat16 arithmetic "
        "(AVX512_BF16, AMX) a compiled step of 100K samples 1.7x the float32 one in one pass, of 4096 about as fast; "
        "near convergence it trains 3-10% worse; on CPUs without it (AVX2 alone) the products are emulated and "
        "the step is about 7x slower than in float32 (docs/BENCHMARKS.md)"))
    latent_prior: float = Field(0.0, ge=0.0, allow_inf_nan=False, description=(
        "weight of a Gaussian prior on each training material's latent code about 0.5, where every code "
        "and every fit starts (an auto-decoder's code prior, as DeepSDF's): each sample's loss gains "
        "latent_prior times its material's mean squared distance from 0.5 over the code; 0: none (the paper)"))

    @model_validator(mode="after")
    def _check_lr(self) -> "TrainSpec":
        if self.lr_final is not None and self.lr_final > self.lr:
            raise ValueError(f"lr_final ({self.lr_final}) must not exceed lr ({self.lr})")
        return self


RAY_RESOURCE_UNIT = 0.0001  # the smallest fraction of a resource Ray can express


class ResourcesSpec(_Strict):
    cpus_per_candidate: float = Field(1.0, ge=RAY_RESOURCE_UNIT)
    gpus_per_candidate: float = Field(0.0, ge=0.0)

    @model_validator(mode="after")
    def _expressible(self) -> "ResourcesSpec":
        if 0 < self.gpus_per_candidate < RAY_RESOURCE_UNIT:
            raise ValueError(f"gpus_per_candidate: {self.gpus_per_candidate} is neither 0 nor at least "
                             f"{RAY_RESOURCE_UNIT}, the smallest fraction Ray can express")
        return self


class BudgetSpec(_Strict):
    """What a job may spend, summed over restarts; when either runs out the job stops at its last
    committed round (STOPPED, reason "budget"). Checked as each candidate finishes, and the wall
    time also while candidates run."""

    wall_s: float | None = Field(None, gt=0.0, description="seconds the job may run (wall clock, all its runs)")
    cpu_s: float | None = Field(None, gt=0.0, description=(
        "CPU-seconds its candidates may hold: each finished candidate's wall time x cpus_per_candidate"))


class JobSpec(_Strict):
    name: str | None = None
    priority: int = Field(0, ge=-1000, le=1000, description=(
        "queued jobs start highest priority first, in submission order within a priority"))
    budget: BudgetSpec = Field(default_factory=BudgetSpec)
    model: str = "ggx"
    alternatives: bool = Field(False, description=(
        "offer each term's alternative analytical formulas (e.g. Beckmann, Student-t at D; a conductor "
        "Fresnel at F) as digits besides its neural modules (neuenh.models.alternatives)"))
    search: SearchSpec = Field(default_factory=SearchSpec)
    module: ModuleSpec = Field(default_factory=ModuleSpec)
    latent_dim: int = Field(27, ge=0)
    train: TrainSpec = Field(default_factory=TrainSpec)
    data: list[DataSource] = Field(min_length=1)
    resources: ResourcesSpec = Field(default_factory=ResourcesSpec)

    @model_validator(mode="before")
    @classmethod
    def _valid_unicode(cls, data: Any) -> Any:
        """JSON can spell a lone UTF-16 surrogate (``"\\ud800"``), which is no character: such text
        cannot be stored or sent back as UTF-8 (one such job name once broke every job listing)."""
        bad = lone_surrogate_path(data)
        if bad is not None:
            raise ValueError(f"{bad or 'the spec'}: text holds a lone surrogate (U+D800..U+DFFF), not valid Unicode")
        return data

    @model_validator(mode="after")
    def _check(self) -> "JobSpec":
        seen: dict[tuple[str, str], int] = {}
        for i, source in enumerate(self.data):  # synthetic sources name their materials alike
            if source.source.startswith("synthetic_"):
                key = (source.source, source.prefix)
                if key in seen:
                    raise ValueError(f"data.{seen[key]} and data.{i} are both {source.source} with prefix "
                                     f"{source.prefix!r}: their material names collide; give one a 'prefix'")
                seen[key] = i
        if self.model not in available_models():
            raise ValueError(f"unknown model {self.model!r}; available: {', '.join(available_models())}")
        if self.alternatives and self.model not in models_with_alternatives():
            raise ValueError(f"alternatives: model {self.model!r} offers none; those that do: "
                             f"{', '.join(models_with_alternatives())}")
        # a score that never fits a kind of material cannot see a candidate that fails it: a search whose
        # held-out set lacked noisy GGX and zoo conductors chose a model that fits both 3x worse than
        # plain GGX (docs/BENCHMARKS.md, issue 23)
        blind = [f"data[{k}] ({source.source})" for k, source in enumerate(self.data) if not source.holdout]
        if self.search.score == "fit" and blind:
            raise ValueError(f"search.score: fit scores candidates on materials held out of every data source, "
                             f"but {', '.join(blind)} holds none out: give it 'holdout: N'")
        counts = dict(zip(self.positions(), self.digit_counts()))
        self.constraints()  # raises on unknown position names
        for name, digit in self.search.fixed.items():
            if not 0 <= digit < counts[name]:
                raise ValueError(f"search.fixed: digit {digit} for {name} is not in 0..{counts[name] - 1}")
        for name, digits in self.search.allowed.items():
            if any(not 0 <= d < counts[name] for d in digits):
                raise ValueError(f"search.allowed: digits {digits} for {name} are not all in 0..{counts[name] - 1}")
        return self

    # -- what the orchestrator needs ---------------------------------------------------------
    def holds_out(self) -> bool:
        """Some data source keeps materials out of training (candidates get a fit score)."""
        return any(source.holdout for source in self.data)

    def model_instance(self, state: str | None = None) -> BRDFModel:
        """The spec's model (its module choices, latent size and alternatives) in ``state``."""
        return _model(self.model, state, self.module.config(), self.latent_dim, self.alternatives)

    def graph(self) -> Graph:
        """The spec's model as a graph (with its alternatives): positions and choices, no torch."""
        return _graph(self.model, self.alternatives)

    def positions(self) -> tuple[str, ...]:
        return self.graph().names

    def digit_counts(self) -> tuple[int, ...]:
        """How many choices each position has (the model's ``digit_counts``, from its graph alone)."""
        return StateEncoding(len(self.module.config().choices)).arities(self.graph())

    def constraints(self) -> Constraints:
        return Constraints.from_names(
            self.positions(), fixed=self.search.fixed, allowed=self.search.allowed,
            max_neural=self.search.max_neural, digit_counts=self.digit_counts(),
            neural=range(1, self.module.config().digits),
        )

    def digits(self) -> int:
        """m of the search's hypercube: the most choices any position has."""
        return max(self.digit_counts())

    def choice_names(self) -> dict[tuple[str, int], str]:
        """(position, digit) -> choice name, for trails (empty for binary states)."""
        return self.model_instance().choice_names()

    def initial_bundle(self, material_names) -> Bundle:
        """Round 0's parent: the analytical model, every material at the paper's initial values."""
        from neuenh.checkpoint import Bundle

        return Bundle.initial(self.model, material_names, self.module.config(), self.latent_dim, self.alternatives)

    def train_config(self, epochs: int | None = None) -> TrainConfig:
        from neuenh.train import TrainConfig

        return TrainConfig(epochs=self.search.epochs_per_round if epochs is None else epochs,
                           lr=self.train.lr, batch_size=self.train.batch_size, lr_final=self.train.lr_final,
                           compile=self.train.compile, precision=self.train.precision,
                           latent_prior=self.train.latent_prior,
                           fit_score=self.search.fit_score.config(self.train.seed) if self.holds_out() else None)

    def polish_config(self) -> TrainConfig:
        """The final state's last training: ``polish_epochs``, lr decayed to ``lr_final`` (lr/100)."""
        return dataclasses.replace(self.train_config(self.search.polish_epochs),
                                   lr_final=self.train.lr_final or self.train.lr / 100)


def neural_weights(spec: JobSpec, state: str) -> int:
    """Neural weights of ``state`` of the spec's model (its modules and latent size)."""
    return spec.model_instance(state).n_weights()


@functools.lru_cache(maxsize=64)
def _graph(model: str, alternatives: bool) -> Graph:
    """Built once per model (specs are validated and asked for positions often); callers must not change it."""
    return get_graph(model, alternatives=alternatives)[0]


@functools.lru_cache(maxsize=512)
def _model(model: str, state: str | None, module_config, latent_dim: int, alternatives: bool) -> BRDFModel:
    """Built once per distinct arguments (specs are validated and asked for positions often); callers
    must not change it."""
    return get_model(model, state=state, module_config=module_config, latent_dim=latent_dim,
                     alternatives=alternatives)


class SpecError(ValueError):
    """An invalid job spec; the message lists each problem with its field path."""


def parse_spec(data: dict) -> JobSpec:
    try:
        return JobSpec.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or 'spec'}: {e['msg']}" for e in exc.errors()
        )
        raise SpecError(f"invalid job spec: {problems}") from None


def load_spec(path: str | Path) -> JobSpec:
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise SpecError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise SpecError(f"{path}: a folder, not a job spec") from None
    except UnicodeDecodeError as exc:
        raise SpecError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    except yaml.YAMLError as exc:
        raise SpecError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise SpecError(f"{path}: a job spec is a mapping, got {type(data).__name__}")
    try:
        return parse_spec(data)
    except SpecError as exc:
        raise SpecError(f"{path}: {exc}") from None
