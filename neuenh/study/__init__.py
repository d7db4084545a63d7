"""The evaluation study: how the models compare on measured materials never trained on.

* ``contenders`` — each model behind one interface: fitted per material, predicting, costing;
* ``nbrdf_fit`` — the per-material NBRDF network (Sztrajman et al. 2021) fitted from scratch;
* ``heldout`` — fit/test splits of a measured material and the held-out log-L1;
* ``comparison`` — one material: every contender fitted, measured, timed and rendered;
* ``registry`` — which models the study compares (the baselines, typed);
* ``summary`` — medians per model and the document a summary renders of itself;
* ``plots`` — the figures; ``report`` — the whole study, as ``neuenh report`` runs it.

Nothing here imports the orchestrator: baselines are trained "like the search" by
``orchestrator.baselines`` and read here as bundles.
"""
