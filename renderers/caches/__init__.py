"""Neural caches: one implementation (NeuralCache) configured per method.

NRC, NIRC and the neural visibility caches are presets of
:class:`CacheConfig` (:func:`nrc_config`, :func:`nirc_config`,
:func:`visibility_config`) over :class:`NeuralCache`; see docs/design.md
("Methods in one paragraph each") and the NIRC paper, Sec. 4.1 (loss), 4.4 (architecture) and 4.5
(shared per-surface encoding).

Import after ``renderers.backend.init_backend()`` has selected the variant.
"""

from renderers.caches.cache import NeuralCache, build_mlp
from renderers.caches.config import (
    NETWORK_PRESETS,
    CacheConfig,
    ConvergedTrainingConfig,
    DirectionEncodingConfig,
    HashGridConfig,
    LossConfig,
    MLPConfig,
    OptimizerConfig,
    OutputConfig,
    ScalarEncodingConfig,
    direct_light_config,
    nirc_config,
    nrc_config,
    visibility_config,
)
from renderers.caches.records import TrainingRecords

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
