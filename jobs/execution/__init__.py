"""Execution: the durable job queue, the render-process runner, Dask dispatch, the
sweep task graph, GPU workers, API keys and work estimates. Imports the core
(``jobs.protocol``), the views (``jobs.views``), the studies it runs (``jobs.sweeps``)
and ``jobs.record``; nothing imports it back."""
