"""How much a caching method trains per frame: records, optimizer steps, batch, paths.

The one rule every caching method (``nirc``, ``nrc``) uses; docs/training.md,
"Training budget", has the derivation and its sources.

Sources. NRC [MRNK21] trains 4 optimizer steps of 2^14 = 16384 records per
frame at 1920x1080, i.e. 65536 records = 3.16 % of the pixels; NIRC follows
NRC's training strategy with 4 steps per frame (NIRC paper Sec. 6.2,
"Implementation details") and uses about 2-3 % as many training paths as
pixels (Sec. 4.5); its Sec. 6.1 quotes a NIRC batch of 14,400 (4 x 14,400 =
2.78 % of 1080p). Those settings are for a 1080p frame; applied unchanged to
a 32x32 frame they train on 64 records per pixel.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Literal, Protocol

if TYPE_CHECKING:
    from renderers.caches.config import CacheConfig

#: The papers' frame and per-frame training (NRC [MRNK21]; NIRC Sec. 6.2).
PAPER_PIXELS = 1920 * 1080
PAPER_STEPS = 4
PAPER_BATCH = 16384
#: Default records per frame per pixel: 65536 / 2073600 = 3.16 %.
RECORD_FRACTION = PAPER_STEPS * PAPER_BATCH / PAPER_PIXELS
#: Default floor of records per frame: 4 steps of 1024 (see :func:`frame_training_budget`).
MIN_RECORDS = 4096

BudgetMode = Literal["scaled", "paper"]


class BudgetSettings(Protocol):
    """What the rule reads of a caching method's parameters
    (renderers.methods.cached.CacheTrainingParams)."""

    training_budget: BudgetMode
    train_record_fraction: float
    min_train_records: int
    train_fraction: float
    min_train_paths: int
    record_depth: int


@dataclass(frozen=True)
class TrainingBudget:
    """One frame's training under ``mode``: ``paths`` training paths, ``steps``
    Adam steps of ``batch_size`` records each."""

    mode: BudgetMode
    paths: int
    steps: int
    batch_size: int

    @property
    def records(self) -> int:
        """Records the optimizer draws per frame."""
        return self.steps * self.batch_size

    def describe(self) -> dict[str, int | str]:
        """What a run stores as its cache's training per frame
        (``method_stats['caches']['cache']['per_frame']``)."""
        return {**asdict(self), "records": self.records}


def frame_training_budget(pixels: int, params: BudgetSettings,
                          config: CacheConfig) -> TrainingBudget:
    """The training budget of a frame of ``pixels`` pixels.

    ``S`` = ``config.steps_per_frame``, ``B`` = ``config.batch_size`` (the
    presets: the papers' 4 and 16384), ``N`` = ``pixels``:

    ==========  ===================================================  ===========
    mode        batch per step                                       steps
    ==========  ===================================================  ===========
    ``paper``   B, whatever N (the papers' fixed setting)            S
    ``scaled``  min(B, ceil(max(min_train_records,                   S
                train_record_fraction * N) / S))
    ==========  ===================================================  ===========

    Records per frame R = steps x batch. With the defaults (fraction 3.16 %,
    floor 4096, S = 4, B = 16384):

    ===========  ==========  =====  ==========  =========  ================
    resolution   pixels      batch  records R   paths      R / pixels
    ===========  ==========  =====  ==========  =========  ================
    32x32        1024        1024   4096        4096       4.0
    128x128      16384       1024   4096        4096       0.25
    256x256      65536       1024   4096        4096       0.0625
    512x512      262144      2072   8288        7865       0.0316
    1920x1080    2073600     16384  65536       62208      0.0316
    3840x2160    8294400     16384  65536       248832     0.0079 (cap)
    ===========  ==========  =====  ==========  =========  ================

    Steps stay S at every size: the step count sets how far Adam moves the
    cache per frame (how fast it adapts), the batch only how noisy a step is.
    The floor keeps a batch at >= 1024 records: below that the gradient noise
    of the relative L2 loss grows while a step's time hardly falls (its fixed
    cost, kernel launches and the Adam update of the whole hash grid, does
    not scale with the batch: 4 steps of 256 take 0.7-1x the time of 4 of
    1024 on the 2-core CPU). The cap B keeps the papers' batch as the
    largest, so a frame never trains more than the papers' 65536 records.
    ``steps_per_frame`` 0 (no training) keeps B.

    Training paths: ``max(min_train_paths, ceil(train_fraction * N),
    ceil(R / record_depth))`` in both modes. A path records up to
    ``record_depth`` vertices, so the last term gives every record drawn in
    a frame a slot of its own; valid records per path are fewer (paths leave
    the scene or end by roulette), and a frame with fewer usable records than
    R repeats some (:meth:`renderers.caches.cache.NeuralCache.train`).
    """
    steps, batch = config.steps_per_frame, config.batch_size
    if params.training_budget == "scaled" and steps > 0:
        wanted = max(params.min_train_records, math.ceil(params.train_record_fraction * pixels))
        batch = min(batch, math.ceil(wanted / steps))
    paths = max(params.min_train_paths, math.ceil(params.train_fraction * pixels),
                math.ceil(steps * batch / params.record_depth))
    return TrainingBudget(params.training_budget, paths=paths, steps=steps, batch_size=batch)
