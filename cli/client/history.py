"""``neuenh-client history JOB [--since ROUND]``: a job's committed rounds as a table, with the change
and the gain the service describes (as the dashboard shows them)."""

from __future__ import annotations

from ..tables import table
from .api import Api
from .commands import Commands, job_arg, json_arg, note, print_json


def add_parser(commands: Commands) -> None:
    p = commands.add("history", run, "a job's committed rounds: +X made position X neural, -X analytical again")
    job_arg(p)
    p.add_argument("--since", type=int, default=0, metavar="ROUND", help="only rounds from this one on")
    json_arg(p, "print the service's history (every candidate of every round) as JSON")


def run(args, api: Api) -> int:
    data = api.history(args.job, args.since)
    if args.json:
        print_json(data)
        return 0
    if not data["rounds"]:
        note(f"job {args.job} has no committed round{' from ' + str(args.since) if args.since else ''} yet "
             f"({data['status'].lower()})")
        return 0
    print(history_table(data["rounds"]))
    return 0


def history_table(rounds: list[dict]) -> str:
    """One row per round: parent and winner, the change, the winner's loss and gain, candidates, time;
    the winner's fit score beside its val loss when the job scored candidates on held-out materials."""
    fit = any(r.get("winner_fit_score") is not None for r in rounds)
    rows = [("round", "parent -> winner", "changed", "val loss", *(("fit score",) if fit else ()), "vs start",
             "ok/total", "wall")]
    for r in rounds:
        ok = f"{sum(c['ok'] for c in r['candidates'])}/{len(r['candidates'])}"
        ok += f" ({r['recovered']} recovered)" if r.get("recovered") else ""
        gain = "-" if r["gain_over_start"] is None else f"{-100 * r['gain_over_start']:+.1f}%"
        score = "-" if r.get("winner_fit_score") is None else f"{r['winner_fit_score']:.5f}"
        rows.append((str(r["round"]) + (" polish" if r["kind"] == "polish" else ""),
                     f"{r['parent_state']} -> {r['winner_state']}",
                     r["change"] + (" converged" if r["converged"] else ""),
                     f"{r['winner_val_loss']:.5f}", *((score,) if fit else ()), gain, ok, f"{r['wall_s']:.1f}s"))
    return table(rows, right=tuple(i for i, h in enumerate(rows[0]) if h not in ("parent -> winner", "changed")))
