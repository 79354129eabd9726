"""The evaluation protocol: job specs, the executor (the one place that joins
rendering, metrics and storage), references, cache snapshots, sweeps, equal-time
calibration, reports, plots, quality verdicts and versions. Imports only
``jobs.record`` of ``jobs``."""
