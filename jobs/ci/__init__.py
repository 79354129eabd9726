"""Regression tracking (``nirc-bench ci``): the suite, its statistics, the comparison
against a baseline and a metric's history over commits. Imports the core
(``jobs.protocol``), the views (``jobs.views``) and the record; no other study."""
