"""Views of stored runs, shared by the service and the studies: the charts and their
groups and colours, the PNG figures, the Pareto front and the strongest PT's envelope,
runs side by side, the filters of ``runs list`` and a run's exported files. Imports
only the core (``jobs.protocol``) and the record of ``jobs``; the studies and
execution build on it, the core never imports it."""
