"""Error metrics, FLIP, image files, previews and statistics for nirc-bench.

numpy-only images: float32 (H, W, 3) linear RGB. This package never imports
``jobs``, ``service``, ``renderers``, Mitsuba or Dr.Jit.

- ``errors``: MSE, MRSE, rBias^2 / rVar, efficiency, non-finite accounting
- ``flip``: HDR/LDR FLIP via NVIDIA's ``flip_evaluator``
- ``imageio``: EXR (OpenEXR) and PNG files, written atomically
- ``tonemap`` / ``preview``: the display transform and 8-bit previews
- ``statistics``: pass accumulator, z-test, confidence intervals
- ``checks``: shared input checks and ``MetricError``
"""
