"""Parameter specs: names, widths, valid ranges, the constrained mapping used in optimisation.

Every analytical parameter of a model has a valid range ``[low, high]``. Optimisers work on an
unconstrained *raw* value; the physical value is ``low + (high - low) * sigmoid(raw)`` (on a
logarithmic axis for ``scale="log"``), so no optimiser step can leave the range. Neural modules
read the *unit* value, the position inside the range in ``[0, 1]``, which keeps their inputs
well conditioned whatever the physical units.

Initialisation follows the paper (Sec. 4.3): the mean of the valid range (alternative terms'
parameters may name another start).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterable, Literal, Mapping

if TYPE_CHECKING:
    import torch

# Raw values are clipped here when inverting the mapping at a range boundary (sigmoid(17) = 1 - 4e-8).
_RAW_LIMIT = 17.0


@dataclass(frozen=True)
class ParamSpec:
    """One analytical parameter: ``width`` components sharing the range ``[low, high]``."""

    name: str
    width: int
    low: float
    high: float
    scale: Literal["linear", "log"] = "linear"
    doc: str = ""
    start: float | None = None  # the initial value when not the range's mean (alternative terms)

    def __post_init__(self) -> None:
        if not self.high > self.low:
            raise ValueError(f"parameter {self.name}: empty range [{self.low}, {self.high}]")
        if self.scale == "log" and self.low <= 0:
            raise ValueError(f"parameter {self.name}: a log-scale range must be positive")
        if self.start is not None and not self.low <= self.start <= self.high:
            raise ValueError(f"parameter {self.name}: start {self.start} outside [{self.low}, {self.high}]")

    @property
    def init(self) -> float:
        """The paper's initial value, the mean of the valid range, unless ``start`` says otherwise
        (an alternative term's parameters start where it equals, or nears, the original term)."""
        return 0.5 * (self.low + self.high) if self.start is None else self.start

    def _axis_bounds(self) -> tuple[float, float]:
        if self.scale == "log":
            return math.log(self.low), math.log(self.high)
        return self.low, self.high

    def to_unit(self, value, xp=None):
        """Physical value -> position in the range, 0 at ``low`` and 1 at ``high``: a torch tensor
        by its own methods, or on the backend ``xp`` of ``neuenh.ops`` (the exporters emit it for a
        model whose parameters arrive at run time)."""
        lo, hi = self._axis_bounds()
        if self.scale == "log":
            value = value.log() if xp is None else xp.log(value)
        return (value - lo) / (hi - lo)

    def from_unit(self, unit: torch.Tensor) -> torch.Tensor:
        lo, hi = self._axis_bounds()
        axis = lo + (hi - lo) * unit
        return axis.exp() if self.scale == "log" else axis

    def from_raw(self, raw: torch.Tensor) -> torch.Tensor:
        """Unconstrained optimisation variable -> physical value, always inside the range."""
        value = self.from_unit(raw.sigmoid())
        # exp/log round-off may land one ulp outside; the contract is "never leaves the range".
        return value.clamp(self.low, self.high)

    def to_raw(self, value: torch.Tensor) -> torch.Tensor:
        unit = self.to_unit(value).clamp(0.0, 1.0)
        return unit.logit().clamp(-_RAW_LIMIT, _RAW_LIMIT)

    def check(self, value: torch.Tensor) -> None:
        """Raise a ValueError naming this parameter if ``value`` is non-finite or out of range."""
        if value.shape[-1] not in (1, self.width):
            raise ValueError(
                f"parameter {self.name!r} has width {self.width}, got a tensor of shape "
                f"{tuple(value.shape)}"
            )
        if not value.isfinite().all():
            raise ValueError(f"parameter {self.name!r} has non-finite values")
        lo, hi = value.min().item(), value.max().item()
        # Allow float32 round-off at the boundaries.
        slack = 1e-6 * max(abs(self.low), abs(self.high), 1.0)
        if lo < self.low - slack or hi > self.high + slack:
            raise ValueError(
                f"parameter {self.name!r} must lie in [{self.low:g}, {self.high:g}], "
                f"got values in [{lo:g}, {hi:g}]"
            )


class ParamSpecs:
    """An ordered set of parameter specs: the analytical parameters of one model."""

    def __init__(self, specs: Iterable[ParamSpec]):
        self._specs = tuple(specs)
        names = [s.name for s in self._specs]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate parameter names in {names}")
        self._by_name = {s.name: s for s in self._specs}

    def __iter__(self):
        return iter(self._specs)

    def __len__(self) -> int:
        return len(self._specs)

    def __getitem__(self, name: str) -> ParamSpec:
        return self._by_name[name]

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self._specs)

    @property
    def total_width(self) -> int:
        """Number of scalar analytical parameters (12 for GGX)."""
        return sum(s.width for s in self._specs)

    def validate(
        self, params: Mapping[str, torch.Tensor], n: int, extra: Iterable[str] = ()
    ) -> dict[str, torch.Tensor]:
        """Check names, widths and ranges of user-given values; broadcast each to ``(n, width)``.

        ``extra`` names keys that are allowed besides the specs (e.g. ``latent``); they are
        returned as given.
        """
        import torch  # (here, not at the top: a job spec is checked against the model's specs without torch)

        allowed = set(self.names) | set(extra)
        unknown = sorted(set(params) - allowed)
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown}; this model takes {sorted(allowed)}")
        missing = [name for name in self.names if name not in params]
        if missing:
            raise ValueError(f"missing parameter(s) {missing}")
        out: dict[str, torch.Tensor] = {}
        for spec in self._specs:
            value = torch.as_tensor(params[spec.name])
            if value.ndim == 0:
                value = value.reshape(1)
            spec.check(value)
            try:
                out[spec.name] = torch.broadcast_to(value, (n, spec.width))
            except RuntimeError:
                raise ValueError(
                    f"parameter {spec.name!r} of shape {tuple(value.shape)} does not broadcast "
                    f"to ({n}, {spec.width})"
                ) from None
        for name in extra:
            if name in params:
                out[name] = torch.as_tensor(params[name])
        return out

    def init_values(self, dtype: torch.dtype | None = None) -> dict[str, torch.Tensor]:
        """The paper's initial value of every parameter, shape ``(width,)`` (float32 by default)."""
        import torch

        return {s.name: torch.full((s.width,), s.init, dtype=dtype or torch.float32) for s in self._specs}

    def unit_vector(self, values: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """Concatenate all parameters as unit values, in spec order: the modules' input."""
        import torch

        return torch.cat([s.to_unit(values[s.name]) for s in self._specs], dim=-1)
