"""Method comparisons: error against time (the Pareto front and the speed-up at equal
error) and the Fig. 7 table at equal spp and equal time. Imports the core
(``jobs.protocol``), the views (``jobs.views``), the cost model (``jobs.costs``)
and the record; no other study."""
