"""Neural caches: one implementation (NeuralCache) configured per method.

NRC, NIRC and the neural visibility caches are presets of
:class:`CacheConfig` (:func:`nrc_config`, :func:`nirc_config`,
:func:`visibility_config`) over :class:`NeuralCache`; see docs/design.md
("Methods in one paragraph each") and the NIRC paper, Sec. 4.1 (loss), 4.4 (architecture) and 4.5
(shared per-surface encoding).

Use the cache (``NeuralCache``, ``TrainingRecords``) after
``renderers.backend.init_backend()`` has selected the variant; the configs
(``renderers.caches.config``) need no backend.
"""

import importlib
from typing import Any

#: Where each export lives. Loaded on first use (PEP 562), so that validating a
#: cache config (renderers.caches.config: pydantic only) does not import Mitsuba,
#: e.g. when the service checks a submission's parameters.
_EXPORTS = {
    "NeuralCache": "renderers.caches.cache",
    "build_mlp": "renderers.caches.cache",
    "TrainingRecords": "renderers.caches.records",
    **{name: "renderers.caches.config" for name in (
        "NETWORK_PRESETS", "CacheConfig", "ConvergedTrainingConfig",
        "DirectionEncodingConfig", "HashGridConfig", "LossConfig", "MLPConfig",
        "OptimizerConfig", "OutputConfig", "ScalarEncodingConfig", "direct_light_config",
        "nirc_config", "nrc_config", "visibility_config")},
}


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


__all__ = [
    "NETWORK_PRESETS",
    "CacheConfig",
    "ConvergedTrainingConfig",
    "DirectionEncodingConfig",
    "HashGridConfig",
    "LossConfig",
    "MLPConfig",
    "NeuralCache",
    "OptimizerConfig",
    "OutputConfig",
    "ScalarEncodingConfig",
    "TrainingRecords",
    "build_mlp",
    "direct_light_config",
    "nirc_config",
    "nrc_config",
    "visibility_config",
]
