"""Plain text both command lines print (``neuenh`` and ``neuenh-client``): aligned tables, a fit
report, a scene plan's frame totals, a command's help. Pure formatting of the JSON the commands already hold, so the
local command and the service's client print the same thing for the same result.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence


def help_description(doc: str) -> str:
    """A command's ``--help`` text from its module doc (a title line, an indented synopsis, then
    the text): the text alone, as argparse's own usage line already gives the synopsis."""
    return doc.split("\n\n", 2)[2]


def table(rows: Sequence[Sequence[str]], right: Collection[int] = ()) -> str:
    """``rows`` (the first is the header) as columns two spaces apart; the columns in ``right``
    right-aligned (numbers), the others left-aligned; no trailing blanks."""
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths))).rstrip()
                     for r in rows)


def against_plain(enhanced: float, plain: float, state: str, plain_name: str = "plain GGX") -> str:
    """The validation loss of the model at ``state`` against ``plain_name``'s trained for the same
    epochs, in words that stay true when the enhancement loses (a short search can end above the plain
    model) and when ``state`` is the plain model itself (no enhancement to credit)."""
    if set(state) == {"0"}:  # every position at its original term: the very model the baseline trains
        return (f"the search kept {plain_name}: no module paid on this data "
                f"({100 * abs(1 - enhanced / plain):.1f}% {'below' if enhanced < plain else 'above'} one run of as many epochs)")
    if enhanced < plain:
        return f"the enhancement lowers the validation loss by {100 * (1 - enhanced / plain):.1f}%"
    return f"the enhancement does not lower the validation loss: {100 * (enhanced / plain - 1):.1f}% above {plain_name}'s"


# A training loss that still fell by more than this over the last quarter of its epochs had not
# levelled off (the quickstart's plain GGX: 22 % at 30 epochs, 12 % at 60, 2 % at 200;
# docs/BENCHMARKS.md, "Search rounds and scaling", stop 48).
STILL_LEARNING_DROP = 0.05


def last_quarter_drop(epoch_losses: Sequence[float]) -> float | None:
    """How much a training loss fell over the last quarter of its epochs, relative to where that
    quarter started (1 - last / earlier); None for fewer than 4 epochs or a loss that was not positive."""
    quarter = len(epoch_losses) // 4
    if quarter == 0 or not epoch_losses[-1 - quarter] > 0:
        return None
    return 1.0 - epoch_losses[-1] / epoch_losses[-1 - quarter]


def still_learning(name: str, epoch_losses: Sequence[float]) -> str:
    """The caveat a comparison at equal epochs needs when ``name``'s training loss had not levelled
    off (it may order the other way trained longer), else ""."""
    drop = last_quarter_drop(epoch_losses)
    if drop is None or drop <= STILL_LEARNING_DROP:
        return ""
    return (f"at equal epochs only: {name}'s training loss still fell {100 * drop:.1f}% over its last "
            f"{len(epoch_losses) // 4} epochs")


def fit_report(report: dict) -> str:
    """A fit's report (``neuenh fit --json``'s, or ``POST /v1/jobs/{id}/fit``'s answer): a line for
    the fit, then one per material with its loss, its parameter count and capacity, and its analytical
    parameters (the latent code and corrections left out)."""
    protocol = report["protocol"]  # the protocol's name and budgets (neuenh.fit)
    budget = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in protocol.items()
                       if k != "name" and isinstance(v, int) and not isinstance(v, bool))
    encoder = " with the encoder's start" if protocol.get("encoder_start") else ""
    lines = [f"{report['model']} (state {report['state']}), {protocol['name']} fit ({budget}){encoder} "
             f"in {report['wall_s']:.1f} s"]
    for m in report["materials"]:
        p = m["params"]
        scalars = "  ".join(f"{k}={_values(v)}" for k, v in p.items())
        heldout = f"  held-out {m['heldout_log_l1']:.5f}" if "heldout_log_l1" in m else ""
        lines.append(f"  {m['name']}: log-L1 {m['loss']:.5f}{heldout}  {m['params_per_material']} parameters "
                     f"({m['capacity']})  {scalars}")
    if "predictions" in report:
        lines.append(f"predictions written to {report['predictions']}")
    if "bundle" in report:
        lines.append(f"bundle written to {report['bundle']}")
    return "\n".join(lines)


def plan_totals(totals: dict) -> str:
    """A scene plan's frame cost and error against choosing the richest or the cheapest rung everywhere."""
    p, r, c = totals["plan"], totals["richest"], totals["cheapest"]
    return (f"frame: plan {p['cost_ns']:.0f} ns, error {p['error']:.4f} | richest everywhere {r['cost_ns']:.0f} ns, "
            f"{r['error']:.4f} | cheapest everywhere {c['cost_ns']:.0f} ns, {c['error']:.4f}")


def _values(values: list[float]) -> str:
    return f"{values[0]:.4g}" if len(values) == 1 else "(" + ", ".join(f"{v:.3g}" for v in values) + ")"
