"""Small job specs for fast orchestrator tests."""

from orchestrator.spec import parse_spec


def tiny_spec(**search):
    return parse_spec({
        "search": {"epochs_per_round": 1, "max_rounds": 3, **search},
        "train": {"batch_size": 1000, "lr": 5e-3},
        "data": [{"source": "synthetic_zoo", "materials": 2, "samples": 300, "seed": 1}],
    })
