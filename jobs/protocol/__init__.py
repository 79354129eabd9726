"""The core of one job: specs and the typed job, the executor (the one place that
joins rendering, metrics and storage), references, results, quality verdicts,
versions, provenance, the scene store, equal-time calibration and the cost model,
plots, exports and queries over stored runs. Imports only ``jobs.record`` of
``jobs``; the studies (``jobs.sweeps``, ``jobs.pareto``, ``jobs.ci``,
``jobs.stress``) build on it and it never imports them."""
