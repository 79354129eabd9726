"""Training records: what a renderer hands a neural cache to learn from.

One record is one (input, target) pair gathered along a training path: the
shading point's position, normal, roughness and albedo(s), the query
direction, and the Monte Carlo estimate of what the cache should predict
(for NIRC the radiance reflected toward x from the next vertex without its
emission, NIRC paper Eq. 8-9; for NRC the outgoing radiance; for visibility
caches the per-light visibility). ``valid`` masks lanes whose training path
produced no usable sample (pdf 0, a miss: ~7 % of NIRC queries).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import drjit as dr
import mitsuba as mi


@dataclass
class TrainingRecords:
    """Dr.Jit arrays of one width N (see module docstring).

    ``normal``/``roughness``/``albedo``/``albedo_spec``/``direction`` may be
    None when the cache's config does not use that input. ``target`` is a
    Color3f (RGB caches) or a list of ``n_outputs`` Floats / an ``ArrayXf``.
    """

    position: mi.Point3f
    target: Any
    normal: mi.Vector3f | None = None
    roughness: mi.Float | None = None
    albedo: mi.Color3f | None = None
    direction: mi.Vector3f | None = None
    albedo_spec: mi.Color3f | None = None
    valid: mi.Bool | None = None

    def __len__(self) -> int:
        return dr.width(self.position)

    def check_widths(self) -> None:
        """Raise ValueError unless every field has width N (or 1: a constant)."""
        n = len(self)
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None:
                continue
            widths = ({dr.width(t) for t in self.target_rows()} if f.name == "target"
                      else {dr.width(v)})
            if not widths <= {1, n}:
                raise ValueError(f"training record field '{f.name}' has width "
                                 f"{sorted(widths)}, expected {n} (the width of position) or 1")

    def target_rows(self) -> list[mi.Float]:
        """The target as a list of Float rows (one per network output)."""
        return [mi.Float(t) for t in self.target]

    def gather(self, index: mi.UInt32) -> TrainingRecords:
        """The records at ``index`` (a new TrainingRecords of width len(index))."""
        values: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None:
                values[f.name] = None
            elif f.name == "target":
                values[f.name] = [t if dr.width(t) == 1 else dr.gather(mi.Float, t, index)
                                  for t in self.target_rows()]
            elif dr.width(v) == 1 and f.name != "position":
                values[f.name] = v  # a constant broadcasts to any width
            else:
                values[f.name] = dr.gather(type(v), v, index)
        return TrainingRecords(**values)

    def finite_inputs(self) -> mi.Bool:
        """Lanes whose inputs (position, normal, ...) are all finite."""
        ok = mi.Bool(True)
        for name in ("position", "normal", "roughness", "albedo", "direction", "albedo_spec"):
            v = getattr(self, name)
            if v is not None:
                ok &= dr.all(dr.isfinite(v)) if dr.depth_v(v) > 1 else dr.isfinite(v)
        return ok

    def finite_targets(self) -> mi.Bool:
        ok = mi.Bool(True)
        for t in self.target_rows():
            ok &= dr.isfinite(t)
        return ok
