"""Computational graphs of analytical BRDFs, enhancement states, and the torch model of a state.

A model is an ordered binary tree (micrograd-style): leaves are *terms* (the semantic nodes of the
paper: M, S, D, F, G, 1/E for GGX), inner nodes are *operators* (+ or ×) that record their ordered
operands. Every term and operator is a *position*; positions are ordered terms first (left to
right), then operators bottom-up, and that order never changes, so state strings and checkpoints
reproduce.

An *enhancement state* is one digit per position (paper Sec. 4.1): 0 keeps the original term or
operator, digit k >= 1 replaces it with neural module choice k (see ``modules.ModuleConfig``).
``BRDFModel`` is the torch module of one state: the analytical graph plus the neural modules its
non-zero digits call for. Per-material parameters live outside it (``materials.MaterialTable``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Literal, Mapping, Sequence

import torch
from torch import nn

from .modules import ModuleConfig, NeuralModule, module_seed
from .params import ParamSpecs
from .shading import Shading, make_shading

if TYPE_CHECKING:
    from .specialize import SpecializedBRDF

# Digits of a state string: 0-9 then a-z, so m-ary states up to m = 36 stay one character each.
_DIGITS = "0123456789abcdefghijklmnopqrstuvwxyz"

LATENT = "latent"  # the key of the neural (latent) parameters in a params mapping


@dataclass(frozen=True, eq=False)
class Term:
    """A leaf of the graph: one semantic term and its analytic formula."""

    name: str
    width: int  # 1 (scalar) or 3 (RGB)
    formula: Callable[[Shading], torch.Tensor]  # Shading -> (n, width)
    reads_directions: bool  # its module then also reads wi, wo (paper Fig. 4, left vs centre)


@dataclass(frozen=True, eq=False)
class Operator:
    """An inner node: ``left op right`` with ``op`` one of ``+`` and ``*``."""

    op: Literal["+", "*"]
    left: "Expr"
    right: "Expr"

    @property
    def name(self) -> str:
        # Named by what it computes, e.g. "S*D*F": unique in a tree and readable in a history.
        return f"{self.left.name}{self.op}{self.right.name}"

    @property
    def width(self) -> int:
        return max(self.left.width, self.right.width)


Expr = Term | Operator


def add(left: Expr, right: Expr) -> Operator:
    return Operator("+", left, right)


def mul(*factors: Expr) -> Expr:
    """Left-associative product: ``mul(a, b, c) = (a × b) × c``, as in the paper's graph."""
    out = factors[0]
    for factor in factors[1:]:
        out = Operator("*", out, factor)
    return out


class Graph:
    """An ordered expression tree with stable position names."""

    def __init__(self, root: Expr):
        self.root = root
        terms: list[Term] = []
        operators: list[Operator] = []

        def visit(expr: Expr) -> None:
            if isinstance(expr, Term):
                terms.append(expr)
                return
            visit(expr.left)
            visit(expr.right)
            operators.append(expr)

        visit(root)
        self.positions: tuple[Expr, ...] = (*terms, *operators)
        self.names: tuple[str, ...] = tuple(p.name for p in self.positions)
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"position names must be unique, got {self.names}")
        self.index: dict[str, int] = {name: i for i, name in enumerate(self.names)}

    def __len__(self) -> int:
        return len(self.positions)

    def parse_state(self, state: str | None, digits: int) -> tuple[int, ...]:
        """State string -> digits, with an error that names what is wrong."""
        if state is None:
            return (0,) * len(self)
        if not isinstance(state, str) or len(state) != len(self):
            raise ValueError(
                f"an enhancement state has one digit per position ({len(self)}: "
                f"{', '.join(self.names)}), got {state!r}"
            )
        out = []
        for name, ch in zip(self.names, state.lower()):
            d = _DIGITS.find(ch)
            if not 0 <= d < digits:
                raise ValueError(
                    f"state {state!r}: digit {ch!r} at position {name} is not in 0..{digits - 1}"
                )
            out.append(d)
        return tuple(out)

    @staticmethod
    def format_state(digits: Sequence[int]) -> str:
        return "".join(_DIGITS[d] for d in digits)

    def describe(self, digits: Sequence[int] | None = None) -> str:
        """The formula with neural replacements marked by a hat: ``M + (((S*D)*F^)*^G^)*invE^``."""
        digits = digits or (0,) * len(self)

        def mark(name: str) -> str:
            d = digits[self.index[name]]
            return "" if d == 0 else ("^" if d == 1 else f"^{d}")

        def render(expr: Expr, top: bool) -> str:
            if isinstance(expr, Term):
                return expr.name + mark(expr.name)
            inner = f"{render(expr.left, False)} {expr.op}{mark(expr.name)} {render(expr.right, False)}"
            return inner if top else f"({inner})"

        return render(self.root, True)


class BRDFModel(nn.Module):
    """An analytical BRDF as a graph, in one enhancement state, with the modules that state needs.

    The stable Python API (DESIGN §4): ``positions``, ``param_names`` and
    ``evaluate(wi, wo, params, state=None) -> (n, 3)`` f_r without the cosine factor.
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
        self.specs = specs
        self.module_config = module_config
        self.latent_dim = latent_dim
        self.digits = graph.parse_state(state, module_config.digits)
        self.neural = nn.ModuleDict()
        for position, digit in zip(graph.names, self.digits):
            if digit:
                self.neural[position] = self.fresh_module(position, digit, seed)

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
    def uses_latent(self) -> bool:
        """Whether some neural module replaces a term (and so reads the latent parameters)."""
        return _reads_latent(self.graph, self.digits)

    def describe(self) -> str:
        return self.graph.describe(self.digits)

    def n_weights(self) -> int:
        return sum(p.numel() for p in self.neural.parameters())

    def module_inputs(self, position: str) -> int:
        """Input width of the module replacing ``position`` (paper Fig. 4)."""
        expr = self.graph.positions[self.graph.index[position]]
        if isinstance(expr, Operator):
            return expr.left.width + expr.right.width
        return self.specs.total_width + self.latent_dim + (6 if expr.reads_directions else 0)

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
        position went back to 0 are dropped.
        """
        child = BRDFModel(
            self.name, self.graph, self.specs,
            module_config=self.module_config, latent_dim=self.latent_dim,
        )
        child.digits = self.graph.parse_state(state, self.module_config.digits)
        for position, old, new in zip(self.graph.names, self.digits, child.digits):
            if new and new == old:
                child.neural[position] = copy.deepcopy(self.neural[position])
            elif new:
                child.neural[position] = self.fresh_module(position, new, seed)
        return child

    # -- evaluation --------------------------------------------------------------------------
    def evaluate(
        self,
        wi: torch.Tensor,
        wo: torch.Tensor,
        params: Mapping[str, torch.Tensor],
        state: str | None = None,
    ) -> torch.Tensor:
        """f_r (n, 3), without the cosine factor, clipped at zero.

        ``wi, wo``: (n, 3) unit vectors in the local frame (z = geometric normal). ``params``:
        physical values by name, each broadcastable to (n, width); an enhanced model whose
        modules replace terms also needs ``latent`` (broadcastable to (n, latent_dim)).
        ``state``: evaluate in another state; every non-zero digit must name a module this model
        holds (e.g. the all-zero state of an enhanced model is the analytical formula).
        """
        wi, wo = _check_directions(wi, wo)
        n = wi.shape[0]
        values = self.specs.validate(params, n, extra=(LATENT,))
        digits = self.digits if state is None else self._held_digits(state)
        latent = None
        if self.latent_dim and _reads_latent(self.graph, digits):
            latent = self._check_latent(values.get(LATENT), n)
        values.pop(LATENT, None)
        values = {k: v.to(wi.dtype) for k, v in values.items()}
        return self.forward(wi, wo, values, latent, digits).clamp_min(0.0)

    def forward(
        self,
        wi: torch.Tensor,
        wo: torch.Tensor,
        values: Mapping[str, torch.Tensor],
        latent: torch.Tensor | None,
        digits: Sequence[int] | None = None,
    ) -> torch.Tensor:
        """Unchecked evaluation for training: values are physical, already (n, width).

        Returns f_r (n, 3) without clipping (a neural module may predict a negative value; the
        training loss handles it), exactly 0 below either horizon.
        """
        digits = self.digits if digits is None else digits
        shading = make_shading(wi, wo, values)
        neural_terms = self._neural_term_outputs(digits, shading, values, latent)

        def term(expr: Term, digit: int) -> torch.Tensor:
            return neural_terms[expr.name] if digit else expr.formula(shading)

        return self._combine(digits, term, shading.above)

    def _combine(self, digits: Sequence[int], term: Callable[[Term, int], torch.Tensor],
                 above: torch.Tensor) -> torch.Tensor:
        """The graph's value from its terms' values (``term(expr, digit)``): operators combine
        their operands, or their module does; exactly 0 below either horizon (``above`` false)."""

        def run(expr: Expr) -> torch.Tensor:
            digit = digits[self.graph.index[expr.name]]
            if isinstance(expr, Term):
                return term(expr, digit)
            left, right = run(expr.left), run(expr.right)
            if digit:
                return self.neural[expr.name](
                    torch.cat([left.expand(-1, expr.left.width), right.expand(-1, expr.right.width)], dim=-1)
                )
            return left + right if expr.op == "+" else left * right

        out = run(self.graph.root).expand(-1, 3)
        return torch.where(above, out, torch.zeros_like(out))

    def forward_indexed(
        self,
        wi: torch.Tensor,
        wo: torch.Tensor,
        values: Mapping[str, torch.Tensor],
        latent: torch.Tensor | None,
        material: torch.Tensor,
        digits: Sequence[int] | None = None,
    ) -> torch.Tensor:
        """``forward`` for samples of a table of materials, the training and fitting path.

        ``values``: physical values per *material*, (m, width) each; ``latent`` (m, latent_dim);
        ``material`` (n,) the table row of each sample. Equals ``forward(wi, wo,
        values[material], latent[material])`` up to float rounding, but what depends on the
        material alone is computed once per material: terms that read no direction (their
        formula or their module), and the first-layer contribution of the 12 + latent
        per-material inputs of every module replacing a term (``NeuralModule.forward_indexed``).
        """
        digits = self.digits if digits is None else digits
        # index_select, not [material]: its backward accumulates in a fixed order (bit-identical).
        shading = make_shading(wi, wo, {k: torch.index_select(v, 0, material) for k, v in values.items()})
        per_material = Shading(None, None, None, None, None, None, None, values, None)
        modules_read = any(d and isinstance(p, Term) for p, d in zip(self.graph.positions, digits))
        material_input = None
        if modules_read:
            parts = [self.specs.unit_vector(values).to(wi.dtype)]
            if self.latent_dim:
                parts.append(latent.to(wi.dtype))
            material_input = torch.cat(parts, dim=-1)
            directions = torch.cat([shading.wi.array, shading.wo.array], dim=-1)
        m = material_input.shape[0] if modules_read else next(iter(values.values())).shape[0]

        def term(expr: Term, digit: int) -> torch.Tensor:
            if digit:
                return self.neural[expr.name].forward_indexed(
                    material_input, directions if expr.reads_directions else None, material)
            if not expr.reads_directions:  # a function of the parameters alone: per material
                value = torch.as_tensor(expr.formula(per_material), dtype=wi.dtype)
                return torch.index_select(value.expand(m, expr.width), 0, material)
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
            if digit and isinstance(expr, Term):
                groups.setdefault(expr.reads_directions, []).append(expr.name)
        if not groups:
            return {}
        wi, wo = shading.wi.array, shading.wo.array
        base = [self.specs.unit_vector(values).to(wi.dtype)]
        if self.latent_dim:
            base.append(latent.to(wi.dtype))
        out: dict[str, torch.Tensor] = {}
        for reads_directions, names in groups.items():
            x = torch.cat(base + ([wi, wo] if reads_directions else []), dim=-1)
            out.update((name, self.neural[name](x)) for name in names)
        return out

    def specialize(self, params: Mapping[str, torch.Tensor]) -> "SpecializedBRDF":
        """One material's ``(wi, wo) -> f_r`` with its parameters (the dict ``evaluate`` takes,
        without the batch dimension) folded in: see ``neuenh.specialize``."""
        from .specialize import SpecializedBRDF

        return SpecializedBRDF(self, params)

    def _held_digits(self, state: str) -> tuple[int, ...]:
        digits = self.graph.parse_state(state, self.module_config.digits)
        for position, digit, own in zip(self.graph.names, digits, self.digits):
            if digit and digit != own:
                raise ValueError(
                    f"state {state!r} asks for module {digit} at {position}, but this model holds "
                    f"{'no module' if not own else f'module {own}'} there (its state is {self.state!r})"
                )
        return digits

    def _check_latent(self, latent: torch.Tensor | None, n: int) -> torch.Tensor:
        if latent is None:
            raise ValueError(
                f"this enhanced model ({self.describe()}) needs params['latent'] of width "
                f"{self.latent_dim}"
            )
        latent = torch.as_tensor(latent)
        if latent.ndim == 0 or latent.shape[-1] != self.latent_dim:
            raise ValueError(
                f"params['latent'] must have width {self.latent_dim}, got shape {tuple(latent.shape)}"
            )
        if not torch.isfinite(latent).all():
            raise ValueError("params['latent'] has non-finite values")
        try:
            return torch.broadcast_to(latent, (n, self.latent_dim))
        except RuntimeError:
            raise ValueError(
                f"params['latent'] of shape {tuple(latent.shape)} does not broadcast to "
                f"({n}, {self.latent_dim})"
            ) from None


def _reads_latent(graph: Graph, digits: Sequence[int]) -> bool:
    return any(d and isinstance(p, Term) for p, d in zip(graph.positions, digits))


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
