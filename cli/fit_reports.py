"""Fit reports as the commands read them: the JSON ``neuenh fit --json`` prints (and ``POST
/v1/jobs/{id}/fit`` answers), ``{"model": ..., "state": ..., "materials": [{"name": ..., "params":
{...}, "latent": ..., "capacity": ..., ...}]}``. ``neuenh render --params``, ``neuenh export
--params`` and ``neuenh data slice --params`` read them here, with the same checks and the same messages.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from neuenh.capacities import ANALYTICAL_CAPACITIES

if TYPE_CHECKING:  # torch (~1.5 s) is imported when a report is read, not for a command's --help
    from neuenh.materials import MaterialParams


def read_fit_report(path: Path, model, flag: str = "--params") -> dict[str, MaterialParams]:
    """Every material of the report at ``path`` (given as ``flag``), in its order: a fit of ``model``
    (the model name and state the report names must be ``model``'s; a hand-written file
    of ``materials`` alone is taken as it is), each material with the latent code ``model`` reads
    unless it was fitted at an analytical capacity. A ValueError names the file and what is wrong."""
    import json

    from neuenh.materials import MaterialParams

    where = f"{flag} {path}"
    if path.is_dir():  # `neuenh fit -o DIR` writes a bundle, which is a model with its materials
        raise ValueError(f"{where}: a folder, not a fit report; a bundle written by `neuenh fit -o` is given as the "
                         "model itself, a fit report is what `neuenh fit --json` prints")
    if not path.exists():
        raise ValueError(f"{where}: no such file")
    if not path.is_file():
        raise ValueError(f"{where}: not a regular file")
    try:
        report = json.loads(path.read_text())
        entries = [(str(m["name"]), m) for m in report["materials"]]
        named, state = report.get("model"), report.get("state")
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{where}: not a fit report (neuenh fit --json): not JSON ({exc})") from None
    except (KeyError, TypeError, AttributeError):
        raise ValueError(f"{where}: not a fit report (neuenh fit --json): expected "
                         '{"model": ..., "state": ..., "materials": [{"name": ..., "params": {...}}, ...]}') from None
    if named not in (None, model.name) or state not in (None, model.state):
        raise ValueError(f"{path} is a fit of {named or 'a model'} in state {state or '(not named)'}, but the model is "
                         f"{model.name} in state {model.state}; give the model it was fitted with")
    if not entries:
        raise ValueError(f"{where}: holds no materials")
    fitted = {}
    for name, entry in entries:
        try:
            fitted[name] = MaterialParams.from_json(entry)
        except ValueError as exc:
            raise ValueError(f"{path}: material {name!r}: {exc}") from None
        if model.uses_latent and fitted[name].latent is None and fitted[name].capacity not in ANALYTICAL_CAPACITIES:
            raise ValueError(f"{path}: material {name!r} has no latent code, which {model.name} in state "
                             f"{model.state} reads")
    return fitted
