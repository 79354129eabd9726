"""Regression tracking (``nirc-bench ci``): the suite, its statistics, the comparison
against a baseline and a metric's history over commits. Imports the core
(``jobs.protocol``) and the record; no other study."""
