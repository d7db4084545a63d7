"""Per-material parameters: one material's record (``MaterialParams``) and the table of every
material a model is trained on or fitted to (``MaterialTable``).

A material carries its *analytical* parameters (physical values by name), its *latent code* (the
neural parameters every module replacing a term reads; paper Sec. 4.3) and, optionally,
*corrections*: per-material deltas of the shared module weights that an adaptive-capacity fit frees
(issue 23). ``MaterialParams`` holds the three for one material and is what ``BRDFModel.evaluate``,
``BRDFModel.specialize``, the exporters, scene plans and fit reports take.

In a ``MaterialTable`` raw values map to physical ones through the specs' constrained mapping
(``params.ParamSpec``), so they never leave their valid ranges. Latent parameters are unconstrained
and start at 0.5 (paper Sec. 4.3, after Fan et al. 2022).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import Any, Collection, Mapping, Sequence

import torch
from torch import nn

from .capacities import ANALYTICAL_CAPACITIES
from .params import ParamSpecs

LATENT_INIT = 0.5
# The latent code's name where a flat list of named inputs holds it beside the analytical
# parameters: a generic ONNX graph's input, a GLSL parameter layout, EXR channels, a materials file.
LATENT_NAME = "latent"


@dataclass(frozen=True, eq=False)
class MaterialParams:
    """One material's parameters, as a model reads them. Validated on construction.

    * ``values``: physical analytical values by parameter name, each a 1-D tensor ``(width,)``
      (a scalar becomes ``(1,)``). ``BRDFModel.evaluate`` also accepts rows ``(n, width)``: n
      samples' materials side by side (then no corrections: a correction is one material's).
    * ``latent``: the latent code ``(latent_dim,)`` (or ``(n, latent_dim)`` with rows), or None
      when the model reads none.
    * ``corrections``: per-material deltas of module weights: key of ``model.neural.state_dict()``
      (e.g. ``"F.layers.3.weight"``) -> a dense delta of that tensor's shape; the material's module
      weights are ``shared + delta``. Empty: none.
    * ``capacity``: the fit capacity that produced the record (``"analytical"``, ``"latent"``,
      ``"last-layer"``, ...); left out it is derived: ``"analytical"`` without latent and
      corrections, ``"latent"`` with a latent code, ``"corrections"`` with corrections.
    * ``correction_params``: how many free parameters per material the corrections stand for, set
      by the fit that made them: a low-rank correction ``U @ V`` counts the factors' size, not the
      dense delta's. Left out: the dense deltas' element count.

    ``n_params`` is the material's count of free parameters: the values' widths, plus the latent's
    width, plus ``correction_params`` — what every "parameters per material" figure shows.
    """

    values: Mapping[str, torch.Tensor]
    latent: torch.Tensor | None = None
    corrections: Mapping[str, torch.Tensor] = field(default_factory=dict)
    capacity: str | None = None
    correction_params: int | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.values, Mapping):
            raise TypeError(f"MaterialParams.values must map parameter names to tensors, got {type(self.values).__name__}")
        if LATENT_NAME in self.values:
            raise ValueError(f"MaterialParams.values holds a {LATENT_NAME!r} key; pass the latent code as "
                             f"MaterialParams(values, latent=...)")
        values = {str(name): _tensor(value, f"parameter {name!r}") for name, value in self.values.items()}
        latent = None if self.latent is None else _tensor(self.latent, "the latent code")
        corrections = {str(key): _tensor(delta, f"correction {key!r}", max_ndim=None)
                       for key, delta in self.corrections.items()}
        batched = any(v.ndim == 2 for v in values.values()) or (latent is not None and latent.ndim == 2)
        if batched and corrections:
            raise ValueError("corrections belong to one material: its values must be 1-D (width,), not rows")
        if self.correction_params is not None:
            if not isinstance(self.correction_params, int) or self.correction_params < 0:
                raise ValueError(f"correction_params must be a count >= 0, got {self.correction_params!r}")
            if not corrections and self.correction_params:
                raise ValueError(f"correction_params is {self.correction_params} but the record has no corrections")
        capacity = self.capacity
        if capacity is None:
            capacity = "corrections" if corrections else ("latent" if latent is not None else "analytical")
        elif not isinstance(capacity, str) or not capacity:
            raise ValueError(f"capacity must be a non-empty name, got {capacity!r}")
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "latent", latent)
        object.__setattr__(self, "corrections", corrections)
        object.__setattr__(self, "capacity", capacity)

    # -- counts ------------------------------------------------------------------------------
    @property
    def n_params(self) -> int:
        """Free parameters of this material: values' widths + latent width + ``correction_params``
        (the dense deltas' size when the fit did not say)."""
        corrections = self.correction_params
        if corrections is None:
            corrections = sum(delta.numel() for delta in self.corrections.values())
        latent = 0 if self.latent is None else self.latent.shape[-1]
        return sum(v.shape[-1] for v in self.values.values()) + latent + corrections

    # -- conversions -------------------------------------------------------------------------
    @classmethod
    def of(cls, params: "MaterialParams | Mapping[str, Any]") -> "MaterialParams":
        """``params`` as a record: a record as it is, or a plain mapping of analytical values (a
        model that reads no latent code needs no more). An old-style mapping with a ``"latent"``
        key is refused with what to pass instead."""
        if isinstance(params, MaterialParams):
            return params
        if not isinstance(params, Mapping):
            raise TypeError(f"material parameters must be a MaterialParams or a mapping of analytical values, "
                            f"got {type(params).__name__}")
        if LATENT_NAME in params:
            raise ValueError(f"a parameter mapping with a {LATENT_NAME!r} key is no longer taken: pass "
                             f"neuenh.materials.MaterialParams(values, latent=...) (a MaterialTable's as_params(i) "
                             f"gives one)")
        return cls(params)

    def restricted(self, names: Collection[str], latent: bool) -> "MaterialParams":
        """The record with only the values named in ``names`` and the latent code only if ``latent``
        (``BRDFModel.used_params``: what a state reads). A derived capacity is derived again."""
        derived = self.capacity == dataclasses.replace(self, capacity=None).capacity
        return dataclasses.replace(self, values={k: v for k, v in self.values.items() if k in names},
                                   latent=self.latent if latent else None, capacity=None if derived else self.capacity)

    def to(self, dtype: torch.dtype) -> "MaterialParams":
        """The same record with every tensor in ``dtype``."""
        return dataclasses.replace(self, values={k: v.to(dtype) for k, v in self.values.items()},
                                   latent=None if self.latent is None else self.latent.to(dtype),
                                   corrections={k: d.to(dtype) for k, d in self.corrections.items()})

    def to_json(self, digits: int | None = None) -> dict[str, Any]:
        """Plain data (fit reports, ``/fit``, scene plans, exported files): ``params`` (values as
        lists), ``latent`` (a list or None), ``corrections`` (key -> nested lists), ``capacity``,
        ``correction_params`` and ``params_per_material`` (``n_params``, for people; ``from_json``
        ignores it). ``digits``: round values and latent for people (exact floats when None)."""
        def numbers(t: torch.Tensor) -> list[float]:
            return [float(x) if digits is None else round(float(x), digits) for x in t.detach().reshape(-1).tolist()]

        return {"params": {k: numbers(v) for k, v in self.values.items()},
                "latent": None if self.latent is None else numbers(self.latent),
                "corrections": {k: d.detach().tolist() for k, d in self.corrections.items()},
                "capacity": self.capacity, "correction_params": self.correction_params,
                "params_per_material": self.n_params}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> "MaterialParams":
        """The record ``to_json`` wrote (float32 tensors). A ValueError names what is wrong."""
        if not isinstance(data, Mapping) or not isinstance(data.get("params"), Mapping):
            raise ValueError("material parameters must be an object with 'params' (name -> values)")
        if LATENT_NAME in data["params"]:
            raise ValueError(f"'params' holds a {LATENT_NAME!r} key, as files written before MaterialParams did "
                             f"(the latent code is now the material's own {LATENT_NAME!r} field); write it again")
        try:
            latent = data.get("latent")
            return cls({k: torch.tensor(v, dtype=torch.float32) for k, v in data["params"].items()},
                       None if latent is None else torch.tensor(latent, dtype=torch.float32),
                       {k: torch.tensor(v, dtype=torch.float32) for k, v in (data.get("corrections") or {}).items()},
                       data.get("capacity"), data.get("correction_params"))
        except (TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f"material parameters: {exc}") from None


def _tensor(value: Any, what: str, max_ndim: int | None = 2) -> torch.Tensor:
    """``value`` as a floating-point tensor (a scalar as (1,)), checked finite and not too deep."""
    try:
        tensor = torch.as_tensor(value)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise ValueError(f"{what}: not a tensor ({exc})") from None
    if not tensor.is_floating_point():
        tensor = tensor.to(torch.get_default_dtype())
    if tensor.ndim == 0:
        tensor = tensor.reshape(1)
    if max_ndim is not None and tensor.ndim > max_ndim:
        raise ValueError(f"{what} must be (width,) or (n, width), got shape {tuple(tensor.shape)}")
    if not torch.isfinite(tensor.detach()).all():
        raise ValueError(f"{what} has non-finite values")
    return tensor


class MaterialTable(nn.Module):
    """Parameters of ``len(names)`` materials: ``raw[name]`` (m, width), ``latent`` (m, L) and, per
    material, optional corrections (``MaterialParams.corrections``, with their capacity and count).

    ``as_params(i)`` is material ``i``'s record. Corrections are data, not optimisation variables
    of the table: a fit that frees them sets them with ``set_corrections``."""

    def __init__(
        self,
        specs: ParamSpecs,
        names: Sequence[str],
        latent_dim: int,
        raw: Mapping[str, torch.Tensor] | None = None,
        latent: torch.Tensor | None = None,
    ):
        super().__init__()
        self.specs = specs
        self.names = tuple(names)
        m = len(self.names)
        if raw is None:
            raw = {
                s.name: s.to_raw(torch.full((m, s.width), s.init, dtype=torch.float64)).float()
                for s in specs
            }
        if latent is None:
            latent = torch.full((m, latent_dim), LATENT_INIT)
        if set(raw) != set(specs.names):
            raise ValueError(f"material parameters {sorted(raw)} do not match {list(specs.names)}")
        self.raw = nn.ParameterDict(
            {s.name: nn.Parameter(_checked(raw[s.name], (m, s.width), s.name)) for s in specs}
        )
        self.latent = nn.Parameter(_checked(latent, (m, latent_dim), LATENT_NAME))
        # per material: (corrections, capacity, correction_params) — see MaterialParams
        self.fits: list[tuple[dict[str, torch.Tensor], str | None, int | None]] = [({}, None, None)] * m

    @property
    def latent_dim(self) -> int:
        return self.latent.shape[1]

    def __len__(self) -> int:
        return len(self.names)

    def values(self) -> dict[str, torch.Tensor]:
        """Physical values, (m, width) each."""
        return {s.name: s.from_raw(self.raw[s.name]) for s in self.specs}

    def gather(self, material: torch.Tensor) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """Per-sample physical values and latent for material indices ``material`` (n,)."""
        # index_select, not v[material]: the backward of advanced indexing accumulates with a
        # thread-order-dependent sum on CPU, which would break bit-identical training.
        values = {name: torch.index_select(v, 0, material) for name, v in self.values().items()}
        return values, torch.index_select(self.latent, 0, material)

    def set_corrections(self, index: int, corrections: Mapping[str, torch.Tensor], capacity: str | None = None,
                        correction_params: int | None = None) -> None:
        """Material ``index``'s corrections (``MaterialParams``' fields of the same names; checked there)."""
        record = MaterialParams({}, None, corrections, capacity, correction_params)
        self.fits[index] = ({k: v.detach().float().clone() for k, v in record.corrections.items()},
                            capacity, correction_params)

    def coded(self) -> list[int]:
        """Indices of the materials whose record holds a latent code: every one but those fitted at
        an analytical capacity (``capacities.ANALYTICAL_CAPACITIES``), whose row of ``latent`` is only
        where their fit started. A model's mean code and a fit's training codes are taken from these."""
        return [i for i, (_, capacity, _) in enumerate(self.fits) if capacity not in ANALYTICAL_CAPACITIES]

    def latent_codes(self) -> torch.Tensor:
        """(k, latent_dim) the latent codes of the ``coded`` materials, detached."""
        return self.latent.detach()[self.coded()]

    def mean_latent(self) -> torch.Tensor | None:
        """(latent_dim,) the mean of ``latent_codes``, or None when no material holds a code."""
        codes = self.latent_codes()
        return codes.mean(0) if len(codes) else None

    @property
    def has_corrections(self) -> bool:
        return any(corrections for corrections, _, _ in self.fits)

    def subset(self, indices: Sequence[int]) -> "MaterialTable":
        index = torch.as_tensor(list(indices), dtype=torch.long)
        table = MaterialTable(
            self.specs,
            [self.names[i] for i in index.tolist()],
            self.latent_dim,
            {k: v.detach()[index].clone() for k, v in self.raw.items()},
            self.latent.detach()[index].clone(),
        )
        table.fits = [self.fits[i] for i in index.tolist()]
        return table

    @staticmethod
    def concat(tables: Sequence["MaterialTable"]) -> "MaterialTable":
        """The materials of ``tables`` (of one model: the same specs and latent size) in one table, in
        order, each with its record (corrections included)."""
        first = tables[0]
        if any(tuple(t.specs) != tuple(first.specs) or t.latent_dim != first.latent_dim for t in tables):
            raise ValueError("material tables of different models cannot be joined")
        table = MaterialTable(first.specs, [name for t in tables for name in t.names], first.latent_dim,
                              {k: torch.cat([t.raw[k].detach() for t in tables]) for k in first.raw},
                              torch.cat([t.latent.detach() for t in tables]))
        table.fits = [fit for t in tables for fit in t.fits]
        return table

    def tensors(self) -> dict[str, torch.Tensor]:
        """Flat name -> tensor mapping for safetensors: ``raw.<name>``, ``latent`` and, for a
        material ``i`` with corrections, ``correction.<i>.<module weight key>``."""
        out = {f"raw.{k}": v.detach().contiguous() for k, v in self.raw.items()}
        out[LATENT_NAME] = self.latent.detach().contiguous()
        for i, (corrections, _, _) in enumerate(self.fits):
            out.update({f"correction.{i}.{key}": delta.contiguous() for key, delta in corrections.items()})
        return out

    def metadata(self) -> dict[str, str]:
        """The string metadata stored beside ``tensors()``: the names and, when some material has
        corrections or a recorded capacity, each material's capacity and correction count."""
        meta = {"names": json.dumps(list(self.names))}
        if any(capacity is not None or corrections for corrections, capacity, _ in self.fits):
            meta["fits"] = json.dumps([{"capacity": capacity, "correction_params": count}
                                       for _, capacity, count in self.fits])
        return meta

    @classmethod
    def from_tensors(
        cls, specs: ParamSpecs, names: Sequence[str], tensors: Mapping[str, torch.Tensor],
        metadata: Mapping[str, str] | None = None,
    ) -> "MaterialTable":
        """The table ``tensors()`` and ``metadata()`` describe (``names`` as stored there). Files
        without corrections (every bundle before them) load as they always did."""
        raw = {k[len("raw."):]: v for k, v in tensors.items() if k.startswith("raw.")}
        if LATENT_NAME not in tensors:
            raise ValueError(f"material parameters lack {LATENT_NAME!r}")
        latent = tensors[LATENT_NAME]
        table = cls(specs, names, latent.shape[1], raw, latent)
        fits = json.loads((metadata or {}).get("fits", "null")) or [{}] * len(table)
        if len(fits) != len(table):
            raise ValueError(f"material fits describe {len(fits)} materials, the table has {len(table)}")
        corrections: list[dict[str, torch.Tensor]] = [{} for _ in table.names]
        for key, delta in tensors.items():
            if key.startswith("correction."):
                index, _, weight = key[len("correction."):].partition(".")
                if not index.isdigit() or int(index) >= len(table) or not weight:
                    raise ValueError(f"material parameters: {key!r} names no material's correction")
                corrections[int(index)][weight] = delta
        for i, (fit, own) in enumerate(zip(fits, corrections)):
            if own or fit.get("capacity") is not None:
                table.set_corrections(i, own, fit.get("capacity"), fit.get("correction_params"))
        return table

    def as_params(self, index: int) -> MaterialParams:
        """Material ``index``'s record: every analytical value, the latent code and its corrections
        (``BRDFModel.used_params`` keeps what a state reads)."""
        corrections, capacity, count = self.fits[index]
        return MaterialParams({k: v[index].detach() for k, v in self.values().items()},
                              self.latent[index].detach(), corrections, capacity, count)


def _checked(t: torch.Tensor, shape: tuple[int, int], name: str) -> torch.Tensor:
    t = torch.as_tensor(t, dtype=torch.float32).detach().clone()
    if tuple(t.shape) != shape:
        raise ValueError(f"material parameter {name!r} must have shape {shape}, got {tuple(t.shape)}")
    if not torch.isfinite(t).all():
        raise ValueError(f"material parameter {name!r} has non-finite values")
    return t
