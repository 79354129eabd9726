"""The core of one job: specs and the typed job, the executor (the one place that
joins rendering, metrics and storage), references, results and run labels, quality
verdicts, versions, provenance, the scene store and equal-time calibration. Imports
only ``jobs.record`` of ``jobs``; the views (``jobs.views``), the cost model
(``jobs.costs``) and the studies (``jobs.sweeps``, ``jobs.pareto``, ``jobs.ci``,
``jobs.stress``) build on it and it never imports them."""
