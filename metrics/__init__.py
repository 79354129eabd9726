"""Error metrics, FLIP, image files, previews and statistics for nirc-bench.

numpy-only images: float32 (H, W, 3) linear RGB. This package never imports
``jobs``, ``service``, ``renderers``, Mitsuba or Dr.Jit.

- ``registry``: one entry per metric (how it is computed, reduced over seeds,
  stored and shown); every table, plot and API row of metrics is generated from it
- ``errors``: MSE, MRSE, rBias^2 / rVar, efficiency, PSNR of the tone-mapped
  image, non-finite accounting
- ``flip``: HDR/LDR FLIP via NVIDIA's ``flip_evaluator``
- ``imageio``: EXR (OpenEXR) and PNG files, written atomically
- ``tonemap`` / ``preview``: the display transform and 8-bit previews
- ``statistics``: pass accumulator, z-test, confidence intervals
- ``bias_intervals``: the intervals of rBias^2 and rVar, and the per-cache headline rBias^2
- ``checks``: shared input checks and ``MetricError``
- ``quality``: the quality verdict of a run and the metrics it withholds
"""

#: Version of the metric definitions. A stored result records the version it was
#: computed under; results of different versions are never reused or compared.
#: 1: everything before versions were recorded. 2: rBias^2 corrected for the
#: reference's noise floor, degenerate input withheld (metrics.quality). 3: a method that
#: trains a cache per seed reports rBias^2 as the mean of its caches' own values (pooled,
#: opposite biases cancelled); rBias^2 and rVar carry 95 % intervals (metrics.bias_intervals).
METRIC_VERSION = 3
