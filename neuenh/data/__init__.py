"""Data: direction sampling, measured and synthetic materials, sample sets.

``load_measured`` is imported on first use: the table reader (``table``) and the file-format
checks (``errors``) work without torch, which ``neuenh-client`` relies on to validate a table in a
fraction of a second before uploading it.
"""

__all__ = ["load_measured"]


def __getattr__(name: str):
    if name == "load_measured":
        from .measured import load_measured

        return load_measured
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
