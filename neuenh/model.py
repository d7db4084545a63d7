"""The torch model of one enhancement state: ``BRDFModel``.

``BRDFModel`` is the analytical graph of a model (``neuenh.graph``) with the alternatives its state
chooses substituted (``Graph.substitute``, a graph rewrite) plus the neural modules its neural digits
call for (``neuenh.modules``). Per-material parameters live outside it: one material is a
``materials.MaterialParams`` (values, latent code, corrections), many a ``materials.MaterialTable``.
``specialize`` folds one material into a fast evaluator (``neuenh.specialize``).
"""

from __future__ import annotations

import copy
from typing import Any, Callable, Mapping, Sequence

import torch
from torch import nn

from .graph import Expr, Graph, Operator, StateEncoding, Term, apply, fold
from .materials import MaterialParams
from .modules import ModuleConfig, NeuralModule, module_seed
from .ops import TORCH, BatchVec3
from .params import ParamSpec, ParamSpecs
from .rows import RowIndex, gather_rows
from .shading import Shading, frame_of, make_shading
from .specialize import SpecializedBRDF


class BRDFModel(nn.Module):
    """An analytical BRDF as a graph, in one enhancement state, with the modules that state needs.

    The stable Python API (ARCHITECTURE §4): ``positions``, ``param_names`` and
    ``evaluate(wi, wo, params, state=None) -> (n, 3)`` f_r without the cosine factor.

    Parameters: ``module_specs`` are the model's own (the paper's 12 for GGX): every neural module
    reads them. ``specs`` adds the extra parameters of every alternative the graph offers, in
    position order; every material carries them all (so a search's candidates share one material
    table), but only the chosen alternatives read theirs (``used_specs``).
    """

    def __init__(
        self,
        name: str,
        graph: Graph,
        specs: ParamSpecs,
        *,
        state: str | None = None,
        module_config: ModuleConfig = ModuleConfig(),
        latent_dim: int = 27,
        seed: int = 0,
    ):
        super().__init__()
        if latent_dim < 0:
            raise ValueError(f"latent_dim must be >= 0, got {latent_dim}")
        self.name = name
        self.graph = graph
        self.module_specs = specs
        extras: dict[str, ParamSpec] = {}
        for expr in graph.positions:
            for alt in getattr(expr, "alternatives", ()):
                for spec in alt.params:
                    if spec.name in specs or extras.get(spec.name, spec) != spec:
                        raise ValueError(f"parameter {spec.name!r} of {expr.name}[{alt.choice}] clashes with another")
                    extras[spec.name] = spec
        self.specs = ParamSpecs([*specs, *extras.values()]) if extras else specs
        self.module_config = module_config
        self.encoding = StateEncoding(len(module_config.choices))
        self.latent_dim = latent_dim
        self.digits = graph.parse_state(state, self.digit_counts)
        self.neural = nn.ModuleDict()
        for position, digit in zip(graph.names, self.digits):
            if self.is_neural(digit):
                self.neural[position] = self.fresh_module(position, digit, seed)
        self._roots: dict[tuple[int, ...], Expr] = {}

    # -- what the model is ------------------------------------------------------------------
    @property
    def positions(self) -> tuple[str, ...]:
        return self.graph.names

    @property
    def param_names(self) -> tuple[str, ...]:
        return self.specs.names

    @property
    def state(self) -> str:
        return self.graph.format_state(self.digits)

    @property
    def has_alternatives(self) -> bool:
        return any(isinstance(p, Term) and p.alternatives for p in self.graph.positions)

    @property
    def digit_counts(self) -> tuple[int, ...]:
        """How many choices each position has: original, the neural modules, the alternatives."""
        return self.encoding.arities(self.graph)

    def is_neural(self, digit: int) -> bool:
        """Whether ``digit`` (at any position) selects a neural module."""
        return self.encoding.is_neural(digit)

    def choices(self, position: str) -> tuple[str, ...]:
        """The names of ``position``'s choices, by digit: e.g. ``("ggx", "mlp16-32-16",
        "beckmann", ...)`` for GGX's D with alternatives."""
        expr = self.graph.positions[self.graph.index[position]]
        original = expr.choice if isinstance(expr, Term) else ("add" if expr.op == "+" else "multiply")
        neural = tuple("mlp" + "-".join(map(str, hidden)) for hidden in self.module_config.choices)
        return (original, *neural, *(alt.choice for alt in getattr(expr, "alternatives", ())))

    def choice_names(self) -> dict[tuple[str, int], str]:
        """(position, digit) -> choice name for every non-zero digit: what a search trail shows
        when digits mean more than "neural" (``search.describe_change``); empty for binary states."""
        if not self.has_alternatives and self.encoding.modules == 1:
            return {}
        return {(p, d): name for p in self.positions for d, name in enumerate(self.choices(p)) if d}

    def chosen_terms(self, digits: Sequence[int] | None = None) -> dict[str, Term]:
        """Position -> the alternative Term ``digits`` choose there (only positions that choose one)."""
        digits = self.digits if digits is None else digits
        return {expr.name: expr.alternatives[self.encoding.alternative(d)] for expr, d in zip(self.graph.positions, digits)
                if isinstance(expr, Term) and self.encoding.is_alternative(d)}

    def expression(self, digits: Sequence[int] | None = None) -> Expr:
        """The graph's root with the chosen alternatives substituted (neural positions keep their
        original Term: the module replaces it when evaluated)."""
        digits = tuple(self.digits if digits is None else digits)
        if digits not in self._roots:
            self._roots[digits] = self.graph.substitute(self.chosen_terms(digits))
        return self._roots[digits]

    def used_specs(self, digits: Sequence[int] | None = None) -> ParamSpecs:
        """The parameters a state reads: the model's own and its chosen alternatives' extras."""
        extra = {spec.name: spec for term in self.chosen_terms(digits).values() for spec in term.params}
        return ParamSpecs([*self.module_specs, *extra.values()]) if extra else self.module_specs

    def n_material_params(self, digits: Sequence[int] | None = None) -> int:
        """Per-material parameters of a state: its used analytical ones plus the latent when a
        module reads it (39 for the paper's enhanced GGX)."""
        digits = self.digits if digits is None else digits
        latent = self.latent_dim if _reads_latent(self, digits) else 0
        return self.used_specs(digits).total_width + latent

    @property
    def has_modules(self) -> bool:
        """Whether the state has neural modules (else it is an analytical formula, alternatives included)."""
        return any(self.is_neural(d) for d in self.digits)

    def analytical_state(self, keep_alternatives: bool = True) -> str:
        """This state with every neural module back to its original term, and the alternatives the
        search chose kept, or (``keep_alternatives=False``) every position at its original term: the
        model the search started from, e.g. plain GGX."""
        return self.graph.format_state([0 if self.is_neural(d) or not keep_alternatives else d for d in self.digits])

    @property
    def uses_latent(self) -> bool:
        """Whether some neural module replaces a term (and so reads the latent parameters)."""
        return _reads_latent(self, self.digits)

    def describe(self) -> str:
        """The formula with neural positions hatted and alternatives named: ``M + ((S * D[beckmann]) ...``."""
        def mark(position: str, digit: int) -> str:
            if self.encoding.is_alternative(digit):
                return f"[{self.choices(position)[digit]}]"
            return "^" if digit == 1 else f"^{digit}"

        return self.graph.describe(self.digits, mark)

    def n_weights(self) -> int:
        return sum(p.numel() for p in self.neural.parameters())

    def module_inputs(self, position: str) -> int:
        """Input width of the module replacing ``position`` (paper Fig. 4)."""
        expr = self.graph.positions[self.graph.index[position]]
        if isinstance(expr, Operator):
            return expr.left.width + expr.right.width
        return self.module_specs.total_width + self.latent_dim + (6 if expr.reads_directions else 0)

    def fresh_module(self, position: str, digit: int, seed: int) -> NeuralModule:
        expr = self.graph.positions[self.graph.index[position]]
        generator = torch.Generator().manual_seed(module_seed(seed, position, digit))
        return NeuralModule(
            self.module_inputs(position),
            expr.width,
            self.module_config.hidden(digit),
            self.module_config.negative_slope,
            generator,
        )

    # -- candidates --------------------------------------------------------------------------
    def enhance(self, state: str, seed: int) -> "BRDFModel":
        """The candidate for ``state`` built from this (parent) model.

        Modules at positions whose digit is unchanged keep the parent's trained weights (copied);
        newly added or changed modules are freshly initialised from ``seed``; modules whose
        position went back to 0 or to an alternative are dropped.
        """
        child = BRDFModel(
            self.name, self.graph, self.module_specs,
            module_config=self.module_config, latent_dim=self.latent_dim,
        )
        child.digits = self.graph.parse_state(state, self.digit_counts)
        for position, old, new in zip(self.graph.names, self.digits, child.digits):
            if self.is_neural(new) and new == old:
                child.neural[position] = copy.deepcopy(self.neural[position])
            elif self.is_neural(new):
                child.neural[position] = self.fresh_module(position, new, seed)
        return child

    # -- evaluation --------------------------------------------------------------------------
    def evaluate(
        self,
        wi: torch.Tensor,
        wo: torch.Tensor,
        params: MaterialParams | Mapping[str, torch.Tensor],
        state: str | None = None,
    ) -> torch.Tensor:
        """f_r (n, 3), without the cosine factor, clipped at zero.

        ``wi, wo``: (n, 3) unit vectors in the local frame (z = geometric normal). ``params``: a
        ``MaterialParams`` (its values broadcastable to (n, width), the parameters of alternatives
        the state does not choose may be left out; an enhanced model whose modules replace terms
        needs its ``latent``; its ``corrections`` are added to the module weights they name), or a
        plain mapping of the analytical values for a model that reads no latent code. ``state``:
        evaluate in another state; every neural digit must name a module this model holds (e.g.
        the all-zero state of an enhanced model is the analytical formula).
        """
        return self.unclipped(wi, wo, params, state).clamp_min(0.0)

    def unclipped(self, wi: torch.Tensor, wo: torch.Tensor, params: MaterialParams | Mapping[str, torch.Tensor],
                  state: str | None = None) -> torch.Tensor:
        """``evaluate`` without the clip at zero: what the training loss sees (a module may predict
        a negative value)."""
        wi, wo = _check_directions(wi, wo)
        n = wi.shape[0]
        digits = self.digits if state is None else self._held_digits(state)
        params = MaterialParams.of(params)
        values = self.specs.validate(self.complete_params(params.values, digits), n)
        latent = None
        if self.latent_dim and _reads_latent(self, digits):
            latent = self._check_latent(params.latent, n)
        values = {k: v.to(wi.dtype) for k, v in values.items()}
        if not params.corrections:
            return self.forward(wi, wo, values, latent, digits)
        weights = {f"neural.{k}": w for k, w in self.corrected_weights(params.corrections).items()}
        return torch.func.functional_call(self, weights, (wi, wo, values, latent, digits))

    def corrected_weights(self, corrections: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """``shared + delta`` (in the shared weight's dtype) for each module weight a material's
        ``corrections`` name (keys of ``self.neural.state_dict()``); a ValueError names an unknown
        key or a wrong shape."""
        shared = dict(self.neural.named_parameters())
        out = {}
        for key, delta in corrections.items():
            if key not in shared:
                raise ValueError(f"correction {key!r} names no module weight of this model (state {self.state}); "
                                 f"it has {sorted(shared)[:8]}{' ...' if len(shared) > 8 else ''}")
            if tuple(delta.shape) != tuple(shared[key].shape):
                raise ValueError(f"correction {key!r} must have shape {tuple(shared[key].shape)}, got {tuple(delta.shape)}")
            out[key] = shared[key] + delta.to(shared[key].dtype)
        return out

    def used_params(self, params: MaterialParams | Mapping[str, torch.Tensor]) -> MaterialParams:
        """What this state reads of a material: its used analytical values (not those of
        alternatives it does not choose), the latent code only when a module reads it, the
        corrections. Its ``n_params`` is the material's count at this state."""
        return MaterialParams.of(params).restricted(set(self.used_specs().names), self.uses_latent)

    def complete_params(self, params: Mapping[str, torch.Tensor], digits: Sequence[int] | None = None
                        ) -> dict[str, torch.Tensor]:
        """``params`` with the parameters of alternatives the state does not read filled in (their
        initial values), so a user names only what the state uses; a used one missing stays missing
        (``ParamSpecs.validate`` names it)."""
        used = set(self.used_specs(digits).names)
        out = dict(params)
        for spec in self.specs:
            if spec.name not in out and spec.name not in used:
                out[spec.name] = torch.full((spec.width,), spec.init)
        return out

    def forward(self, wi: torch.Tensor, wo: torch.Tensor, values: Mapping[str, torch.Tensor],
                latent: torch.Tensor | None, digits: Sequence[int] | None = None) -> torch.Tensor:
        """Unchecked evaluation for training: values are physical, already (n, width).

        Returns f_r (n, 3) without clipping (a neural module may predict a negative value; the
        training loss handles it), exactly 0 below either horizon.
        """
        digits = self.digits if digits is None else digits
        shading = make_shading(wi, wo, values, TORCH)
        neural_terms = self._neural_term_outputs(digits, shading, values, latent)

        def term(expr: Term, digit: int) -> torch.Tensor:
            return neural_terms[expr.name] if self.is_neural(digit) else expr.formula(shading)

        return self._combine(digits, term, shading.above)

    def combine(self, digits: Sequence[int], term: Callable[[Term, int], Any],
                module: Callable[[Operator, Any, Any], Any]) -> Any:
        """The graph's value in state ``digits`` on any backend, bottom-up: ``term(expr, digit)`` for
        each chosen term (``expr`` the chosen formula's Term; its digit may select a module),
        ``module(op, left, right)`` for an operator whose digit selects a module, else its ``+`` or
        ``*`` of the operands. No horizon mask: the caller applies it."""

        def digit(expr: Expr) -> int:
            return digits[self.graph.index[expr.name]]

        def operator(op: Operator, left, right):
            return module(op, left, right) if self.is_neural(digit(op)) else apply(op, left, right)

        return fold(self.expression(digits), lambda leaf: term(leaf, digit(leaf)), operator)

    def _combine(self, digits: Sequence[int], term: Callable[[Term, int], torch.Tensor],
                 above: torch.Tensor) -> torch.Tensor:
        """``combine`` in torch: an operator's module reads its operands side by side; exactly 0 below
        either horizon (``above`` false)."""

        def module(op: Operator, left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
            return self.neural[op.name](torch.cat([left.expand(-1, op.left.width), right.expand(-1, op.right.width)],
                                                  dim=-1))

        out = self.combine(digits, term, module).expand(-1, 3)
        return torch.where(above, out, torch.zeros_like(out))

    def forward_indexed(
        self,
        wi: torch.Tensor,
        wo: torch.Tensor,
        values: Mapping[str, torch.Tensor],
        latent: torch.Tensor | None,
        material: RowIndex,
        digits: Sequence[int] | None = None,
    ) -> torch.Tensor:
        """``forward`` for samples of a table of materials, the training and fitting path.

        ``values``: physical values per *material*, (m, width) each; ``latent`` (m, latent_dim);
        ``material``: the row of each sample (``rows.RowIndex``: an index or a grid). Equals ``forward(wi, wo,
        values[material], latent[material])`` up to float rounding, but what depends on the
        material alone is computed once per material: the shading frame (tilted normal, rotated
        tangent), terms that read no direction (their formula or their module), and the
        first-layer contribution of the 12 + latent per-material inputs of every module replacing
        a term (``NeuralModule.forward_indexed``).
        """
        digits = self.digits if digits is None else digits
        gather = lambda v: gather_rows(v, material)
        # The shading frame depends on the material alone: built once per material, then gathered.
        frame = frame_of(TORCH, values)
        frame = None if frame is None else tuple(BatchVec3(gather(axis.array)) for axis in frame)
        shading = make_shading(wi, wo, {k: gather(v) for k, v in values.items()}, TORCH, frame=frame)
        per_material = Shading.of_params(values, TORCH)
        modules_read = _reads_latent(self, digits)
        # Both bound either way: torch.compile breaks its graph on a closure over an unbound name.
        material_input = directions = None
        if modules_read:
            parts = [self.module_specs.unit_vector(values).to(wi.dtype)]
            if self.latent_dim:
                parts.append(latent.to(wi.dtype))
            material_input = torch.cat(parts, dim=-1)
            directions = torch.cat([shading.wi.array, shading.wo.array], dim=-1)
        m = material_input.shape[0] if modules_read else next(iter(values.values())).shape[0]

        def term(expr: Term, digit: int) -> torch.Tensor:
            if self.is_neural(digit):
                return self.neural[expr.name].forward_indexed(
                    material_input, directions if expr.reads_directions else None, material)
            if not expr.reads_directions:  # a function of the parameters alone: per material
                value = torch.as_tensor(expr.formula(per_material), dtype=wi.dtype)
                return gather(value.expand(m, expr.width))
            return expr.formula(shading)

        return self._combine(digits, term, shading.above)

    def _neural_term_outputs(
        self,
        digits: Sequence[int],
        shading: Shading,
        values: Mapping[str, torch.Tensor],
        latent: torch.Tensor | None,
    ) -> dict[str, torch.Tensor]:
        """Outputs of the modules replacing terms; modules that read the same input (with or
        without directions) share one concatenated input."""
        groups: dict[bool, list[str]] = {}
        for expr, digit in zip(self.graph.positions, digits):
            if self.is_neural(digit) and isinstance(expr, Term):
                groups.setdefault(expr.reads_directions, []).append(expr.name)
        if not groups:
            return {}
        wi, wo = shading.wi.array, shading.wo.array
        base = [self.module_specs.unit_vector(values).to(wi.dtype)]
        if self.latent_dim:
            base.append(latent.to(wi.dtype))
        out: dict[str, torch.Tensor] = {}
        for reads_directions, names in groups.items():
            x = torch.cat(base + ([wi, wo] if reads_directions else []), dim=-1)
            out.update((name, self.neural[name](x)) for name in names)
        return out

    def specialize(self, params: MaterialParams | Mapping[str, torch.Tensor]) -> SpecializedBRDF:
        """One material's ``(wi, wo) -> f_r`` with its parameters (what ``evaluate`` takes, without
        the batch dimension; corrections folded into the module weights) folded in: see
        ``neuenh.specialize``."""
        return SpecializedBRDF(self, params)

    def _held_digits(self, state: str) -> tuple[int, ...]:
        digits = self.graph.parse_state(state, self.digit_counts)
        for position, digit, own in zip(self.graph.names, digits, self.digits):
            if self.is_neural(digit) and digit != own:
                raise ValueError(
                    f"state {state!r} asks for module {digit} at {position}, but this model holds "
                    f"{'no module' if not own else f'module {own}'} there (its state is {self.state!r})"
                )
        return digits

    def _check_latent(self, latent: torch.Tensor | None, n: int) -> torch.Tensor:
        if latent is None:
            raise ValueError(
                f"this enhanced model ({self.describe()}) needs a latent code of width {self.latent_dim}: "
                f"pass MaterialParams(values, latent=...)"
            )
        latent = torch.as_tensor(latent)
        if latent.ndim == 0 or latent.shape[-1] != self.latent_dim:
            raise ValueError(
                f"the latent code must have width {self.latent_dim}, got shape {tuple(latent.shape)}"
            )
        if not torch.isfinite(latent).all():
            raise ValueError("the latent code has non-finite values")
        try:
            return torch.broadcast_to(latent, (n, self.latent_dim))
        except RuntimeError:
            raise ValueError(
                f"the latent code of shape {tuple(latent.shape)} does not broadcast to "
                f"({n}, {self.latent_dim})"
            ) from None


def _reads_latent(model: BRDFModel, digits: Sequence[int]) -> bool:
    """Whether a neural module replaces a term in ``digits`` (term modules read the latent)."""
    return any(model.is_neural(d) and isinstance(p, Term) for p, d in zip(model.graph.positions, digits))


def _check_directions(wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    wi, wo = torch.as_tensor(wi), torch.as_tensor(wo)
    for label, w in (("wi", wi), ("wo", wo)):
        if w.ndim != 2 or w.shape[1] != 3:
            raise ValueError(f"{label} must have shape (n, 3), got {tuple(w.shape)}")
        if not w.is_floating_point():
            raise ValueError(f"{label} must be a floating-point tensor, got {w.dtype}")
        if not torch.isfinite(w).all():
            raise ValueError(f"{label} has non-finite values")
        norm = torch.linalg.vector_norm(w, dim=1)
        tol = 1e-3 if w.dtype in (torch.float16, torch.bfloat16) else 1e-4
        if ((norm - 1).abs() > tol).any():
            raise ValueError(f"{label} must be unit vectors (norms range {norm.min():.4g}..{norm.max():.4g})")
    if wi.shape != wo.shape:
        raise ValueError(f"wi and wo must have the same shape, got {tuple(wi.shape)} and {tuple(wo.shape)}")
    if wi.dtype != wo.dtype:
        raise ValueError(f"wi and wo must have the same dtype, got {wi.dtype} and {wo.dtype}")
    return wi, wo
