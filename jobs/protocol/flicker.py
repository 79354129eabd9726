"""Flicker of an animated run: how much a method's frames change from one frame to the
next where the scene does not (docs/animation.md, "Flicker").

For consecutive frames f-1, f with references R_{f-1}, R_f (each frame's own,
jobs.protocol.animation) the static region S_f is the pixels whose reference does
not change beyond its own noise in any channel c:

    p in S_f  <=>  |R_f(p,c) - R_{f-1}(p,c)| <= Z * sqrt(V_f(p,c) + V_{f-1}(p,c))  for all c

(V the variance of a reference's mean; frames showing the same state share one
reference, so S_f is then the whole image). A seed's flicker at frame f is the
relative squared frame-to-frame difference over S_f (the MRSE's weighting, eps the
run's):

    D_f = mean_{p in S_f, c} (I_f(p,c) - I_{f-1}(p,c))^2 / (R_f(p,c)^2 + eps)

and the seed's flicker is the mean of D_f over the frames with a static region. For
independent unbiased frames (PT) E[D_f] = 2 rVar of one frame; a cache whose
prediction drifts from frame to frame adds the drift's square. The run's flicker is
the seed mean with a Student-t interval over the K seeds (metrics.recovery's
frame_error_curve).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from metrics.recovery import frame_error_curve

#: Reference noise (standard deviations of the difference) within which a pixel counts
#: as not changed.
STATIC_Z = 3.0


def static_mask(previous: Any, current: Any) -> np.ndarray:
    """(H, W) bool: S_f of the module docstring for two LoadedReferences (or anything with
    ``mean`` and ``variance``); the whole image when they are one reference."""
    if previous is current:
        return np.ones(np.shape(current.mean)[:2], dtype=bool)
    change = np.abs(np.asarray(current.mean, np.float64) - np.asarray(previous.mean, np.float64))
    noise = np.sqrt(np.asarray(current.variance, np.float64)
                    + np.asarray(previous.variance, np.float64))
    return np.all(change <= STATIC_Z * noise, axis=-1)


def frame_flicker(previous_frame: np.ndarray, frame: np.ndarray, reference: np.ndarray,
                  static: np.ndarray, eps: float) -> float | None:
    """D_f of the module docstring; None where the static region is empty."""
    if not static.any():
        return None
    diff = np.asarray(frame, np.float64)[static] - np.asarray(previous_frame, np.float64)[static]
    ref = np.asarray(reference, np.float64)[static]
    return float(np.mean(diff * diff / (ref * ref + eps)))


def seed_flicker(per_frame: list[float | None]) -> float | None:
    """A seed's flicker: the mean of its D_f over the frames with a static region."""
    values = [value for value in per_frame if value is not None]
    return float(np.mean(values)) if values else None


def run_flicker(per_seed: list[float | None], static_fraction: list[float]) -> dict[str, Any]:
    """The run's ``metrics['animation']['flicker']``: the seed mean with its interval, or
    a note saying why there is none (no static pixel, fewer than 2 frames, a
    non-finite seed: never averaged)."""
    base: dict[str, Any] = {"static_z": STATIC_Z,
                            "static_fraction": (float(np.mean(static_fraction))
                                                if static_fraction else None)}
    if not per_seed or any(value is None for value in per_seed):
        return {**base, "mean": None, "low": None, "high": None, "seeds": len(per_seed),
                "note": "no consecutive frames with a static region"}
    values = np.array(per_seed, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        return {**base, "mean": None, "low": None, "high": None, "seeds": len(per_seed),
                "note": "a seed's flicker is NaN or infinite: no mean over seeds is taken"}
    curve = frame_error_curve(values[:, None])
    return {**base, "mean": curve["mean"][0], "seeds": curve["seeds"],
            "low": None if curve["low"] is None else curve["low"][0],
            "high": None if curve["high"] is None else curve["high"][0]}
