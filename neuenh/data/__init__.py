"""Data: direction sampling, measured and synthetic materials, sample sets."""

from .measured import load_measured

__all__ = ["load_measured"]
