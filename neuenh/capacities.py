"""The capacities a fit offers, by name: what ``neuenh fit --capacity``, a scene's ladder and
``POST /v1/jobs/{id}/fit`` accept. Names only, no torch: the CLI's help and a scene file (``neuenh-client
plan``) check them without loading the fit; ``neuenh.fit.capacity.CAPACITIES`` holds what each one
frees, under these names.
"""

from __future__ import annotations

# Capacities that fit an analytical model of the same graph instead of the modules, and whether that
# model keeps the search's alternative terms: ``analytical`` (modules back to their original terms) and
# ``original`` (every position at its original term: the model the search started from, e.g. plain GGX).
ANALYTICAL_CAPACITIES = {"analytical": True, "original": False}
# Capacities that keep the modules: the latent code alone, then per-material corrections of their weights.
MODULE_CAPACITIES = ("latent", "last-layer", "low-rank", "rank-8", "full")
CAPACITY_NAMES = (*ANALYTICAL_CAPACITIES, *MODULE_CAPACITIES)
# What a user may ask for: one capacity, or ``auto`` (chosen per material by validation on its own samples).
CAPACITY_CHOICES = ("auto", *CAPACITY_NAMES)

# The capacity a user's fit takes when not told: ``neuenh fit``, ``POST /v1/jobs/{id}/fit`` and
# ``neuenh-client fit`` (issue 23: "auto the default"). Closer to the measurements than ``latent`` on the
# training sources and the visible RGL materials, at about twice its time: the figures are in
# docs/BENCHMARKS.md, "Stop 55: `auto` the users' default".
USER_CAPACITY = "auto"

# The one description of the choice, for ``neuenh fit``, ``neuenh-client fit`` and the ``/fit`` form.
CAPACITY_HELP = (f"a model with modules: {USER_CAPACITY} (default) chooses per material by validation on its own "
                 "samples, at about twice the time of latent; latent fits the latent code and analytical "
                 "parameters alone; or exactly one of " + ", ".join(c for c in CAPACITY_NAMES if c != "latent"))

__all__ = ["ANALYTICAL_CAPACITIES", "CAPACITY_CHOICES", "CAPACITY_HELP", "CAPACITY_NAMES", "MODULE_CAPACITIES",
           "USER_CAPACITY"]
