"""What a frame costs on this device: the per-stage cost model, fitted from timed
probes and projected to other resolutions, for the Pareto study and the benchmarks
(and any estimate of a job's time in ``jobs.execution``). Imports only the core
(``jobs.protocol``: its interleaved timing rounds) of ``jobs``."""
