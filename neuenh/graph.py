"""Computational graphs of analytical BRDFs and the encoding of enhancement states.

A model is an ordered binary tree (micrograd-style): leaves are *terms* (the semantic nodes of the
paper: M, S, D, F, G, 1/E for GGX), inner nodes are *operators* (+ or ×) that record their ordered
operands. Every term and operator is a *position*; positions are ordered terms first (left to
right), then operators bottom-up, and that order never changes, so state strings and checkpoints
reproduce.

An *enhancement state* is one digit per position (paper Sec. 4.1, with its m-ary extension): the
digit picks one of the position's *choices*, in this order —

* 0: the original term or operator;
* 1..K: a neural module, ``ModuleConfig.choices[k - 1]`` (K = 1 by default: the paper's);
* K+1..: the term's alternative analytical formulas (``Term.alternatives``, e.g. Beckmann or a
  Student-t distribution at GGX's D; ``models.alternatives``), each with its own extra
  per-material parameters. Operators have no alternatives.

So a model without alternatives and one module size has the paper's binary states, unchanged.
``StateEncoding`` names each digit's kind (``ChoiceKind``: original, neural, alternative) and a
position's *arity*, its number of choices; nothing else does digit arithmetic. The torch model of
a state (the graph with the chosen alternatives substituted, ``Graph.substitute``, plus the modules
its neural digits call for) is ``neuenh.model.BRDFModel``. This module imports no torch: a job spec
is checked against its model's positions and arities without it (``neuenh-client submit``).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Callable, Literal, Mapping, Sequence, TypeVar

from .params import ParamSpec
from .shading import Shading

if TYPE_CHECKING:
    import torch

V = TypeVar("V")  # a value on some backend (a torch tensor, a GLSL expression, an ONNX value, ...)

# Digits of a state string: 0-9 then a-z, so m-ary states up to m = 36 stay one character each.
_DIGITS = "0123456789abcdefghijklmnopqrstuvwxyz"


@dataclass(frozen=True, eq=False)
class Term:
    """A leaf of the graph: one semantic term and its analytic formula.

    ``alternatives``: other analytical formulas a state may choose at this position, each a Term
    of the same name with its own ``choice`` name, formula, ``reads_directions`` and the extra
    per-material ``params`` it reads; none may be wider than this term (whose width is the
    position's: an RGB position may hold a scalar formula, which broadcasts)."""

    name: str
    width: int  # 1 (scalar) or 3 (RGB)
    formula: Callable[[Shading], torch.Tensor]  # Shading -> (n, width)
    reads_directions: bool  # its module then also reads wi, wo (paper Fig. 4, left vs centre)
    choice: str = "original"  # this formula's name among the position's choices
    params: tuple[ParamSpec, ...] = ()  # per-material parameters it reads beyond the model's own
    alternatives: tuple["Term", ...] = ()

    def __post_init__(self) -> None:
        for alt in self.alternatives:
            if alt.name != self.name or alt.width > self.width or alt.alternatives:
                raise ValueError(f"alternative {alt.choice!r} of {self.name}: same name, no wider than "
                                 f"{self.width}, no alternatives of its own")


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


def fold(root: Expr, term: Callable[[Term], V], operator: Callable[[Operator, V, V], V],
         given: Callable[[Expr], V | None] = lambda expr: None) -> V:
    """The tree's value bottom-up, on any backend: ``given(expr)`` first (a value known already,
    e.g. a position folded into a constant, or None to go on), else ``term(leaf)`` for a leaf and
    ``operator(op, left, right)`` for an inner node, its operands' values computed first (left,
    then right). The one walk over an expression: ``BRDFModel.combine`` and
    ``specialize.walk`` (the specialized evaluator, its FLOP count and every exporter) use it."""

    def run(expr: Expr) -> V:
        known = given(expr)
        if known is not None:
            return known
        if isinstance(expr, Term):
            return term(expr)
        return operator(expr, run(expr.left), run(expr.right))

    return run(root)


def apply(op: Operator, left, right):
    """The operator's own arithmetic, ``left + right`` or ``left * right``, on any backend."""
    return left + right if op.op == "+" else left * right


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

    def substitute(self, terms: Mapping[str, Term]) -> Expr:
        """The tree with the leaves named in ``terms`` replaced (same names, so the same positions)."""
        if not terms:
            return self.root

        def rebuild(expr: Expr) -> Expr:
            if isinstance(expr, Term):
                return terms.get(expr.name, expr)
            return Operator(expr.op, rebuild(expr.left), rebuild(expr.right))

        return rebuild(self.root)

    def parse_state(self, state: str | None, digits: int | Sequence[int]) -> tuple[int, ...]:
        """State string -> digits, with an error that names what is wrong. ``digits``: how many
        choices each position has (one number for all, or one per position)."""
        counts = (digits,) * len(self) if isinstance(digits, int) else tuple(digits)
        if state is None:
            return (0,) * len(self)
        if not isinstance(state, str) or len(state) != len(self):
            raise ValueError(
                f"an enhancement state has one digit per position ({len(self)}: "
                f"{', '.join(self.names)}), got {state!r}"
            )
        out = []
        for name, ch, count in zip(self.names, state.lower(), counts):
            d = _DIGITS.find(ch)
            if not 0 <= d < count:
                raise ValueError(
                    f"state {state!r}: digit {ch!r} at position {name} is not in 0..{count - 1}"
                )
            out.append(d)
        return tuple(out)

    @staticmethod
    def format_state(digits: Sequence[int]) -> str:
        return "".join(_DIGITS[d] for d in digits)

    def describe(self, digits: Sequence[int] | None = None,
                 mark_digit: Callable[[str, int], str] | None = None) -> str:
        """The formula with neural replacements marked by a hat: ``M + (((S*D)*F^)*^G^)*invE^``.
        ``mark_digit(position, digit)``: the mark of a non-zero digit (default ``^``, ``^k``)."""
        digits = digits or (0,) * len(self)

        def mark(name: str) -> str:
            d = digits[self.index[name]]
            if d == 0:
                return ""
            return mark_digit(name, d) if mark_digit else ("^" if d == 1 else f"^{d}")

        def render(expr: Expr, top: bool) -> str:
            if isinstance(expr, Term):
                return expr.name + mark(expr.name)
            inner = f"{render(expr.left, False)} {expr.op}{mark(expr.name)} {render(expr.right, False)}"
            return inner if top else f"({inner})"

        return render(self.root, True)


class ChoiceKind(str, Enum):
    """What a digit of a state picks at its position."""

    ORIGINAL = "original"  # the model's own term or operator
    NEURAL = "neural"  # a neural module (one of the module sizes)
    ALTERNATIVE = "alternative"  # another analytical formula of the term (Term.alternatives)


@dataclass(frozen=True)
class ModuleConfig:
    """Which neural module each non-zero digit stands for."""

    choices: tuple[tuple[int, ...], ...] = ((16, 32, 16),)
    negative_slope: float = 0.01  # LeakyReLU slope (PyTorch default; the paper does not say)

    def __post_init__(self) -> None:
        if not self.choices:
            raise ValueError("ModuleConfig needs at least one module choice")
        for hidden in self.choices:
            if not hidden or any(int(w) < 1 for w in hidden):
                raise ValueError(f"module hidden widths must be positive, got {hidden}")

    @property
    def digits(self) -> int:
        """m of the m-ary enhancement state: the original term plus one digit per choice."""
        return 1 + len(self.choices)

    def hidden(self, digit: int) -> tuple[int, ...]:
        if not 1 <= digit < self.digits:
            raise ValueError(f"digit {digit} selects no module; this config allows 1..{self.digits - 1}")
        return tuple(self.choices[digit - 1])

    def to_json(self) -> dict:
        return {"choices": [list(c) for c in self.choices], "negative_slope": self.negative_slope}

    @classmethod
    def from_json(cls, data: dict) -> "ModuleConfig":
        return cls(
            choices=tuple(tuple(int(w) for w in c) for c in data["choices"]),
            negative_slope=float(data.get("negative_slope", 0.01)),
        )


@dataclass(frozen=True)
class StateEncoding:
    """The meaning of the digits of a state: 0 the original, ``1..modules`` a neural module
    (``ModuleConfig.choices[digit - 1]``), then the position's alternatives in ``Term.alternatives``
    order. The same at every position; a position's *arity* (number of choices) is
    ``1 + modules + len(alternatives)``."""

    modules: int  # how many module sizes a digit may choose (>= 1)

    def kind(self, digit: int) -> ChoiceKind:
        if digit == 0:
            return ChoiceKind.ORIGINAL
        return ChoiceKind.NEURAL if digit <= self.modules else ChoiceKind.ALTERNATIVE

    def is_neural(self, digit: int) -> bool:
        return self.kind(digit) is ChoiceKind.NEURAL

    def is_alternative(self, digit: int) -> bool:
        return self.kind(digit) is ChoiceKind.ALTERNATIVE

    def module(self, digit: int) -> int:
        """The index into ``ModuleConfig.choices`` of a neural digit."""
        if not self.is_neural(digit):
            raise ValueError(f"digit {digit} selects no module; modules are digits 1..{self.modules}")
        return digit - 1

    def alternative(self, digit: int) -> int:
        """The index into ``Term.alternatives`` of an alternative's digit."""
        if not self.is_alternative(digit):
            raise ValueError(f"digit {digit} selects no alternative; alternatives start at digit {self.modules + 1}")
        return digit - 1 - self.modules

    def arity(self, expr: Expr) -> int:
        """How many choices ``expr``'s position has: original, the modules, the alternatives."""
        return 1 + self.modules + len(getattr(expr, "alternatives", ()))

    def arities(self, graph: Graph) -> tuple[int, ...]:
        """Every position's arity, in ``graph``'s position order."""
        return tuple(self.arity(p) for p in graph.positions)
