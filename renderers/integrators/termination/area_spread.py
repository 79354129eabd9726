"""`area-spread`: the spread heuristic of the Neural Radiance Cache on the hashed grid,
the baseline of the variance-trading paper ([VTT24] Sec. 6, Table 1, with c = 0.01 and
c = 100).

It is the project's spread heuristic itself (spread.py, through sph.py's
:func:`spread_stop`: a > c a_0, never at the first vertex), with c its own parameter
here rather than the neural methods' ``sph_c``.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from renderers.integrators.termination import (
    TerminationPolicy,
    TerminationQuery,
    TerminationSettings,
    register,
)
from renderers.integrators.termination.sph import spread_stop, weight_of


class AreaSpreadParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    # spread.SPREAD_C, written out: reading the registry imports no renderer code.
    c: float = Field(0.01, gt=0.0, le=1e12, description="c of a > c a_0 (NRC: 0.01)")


@register
class AreaSpread(TerminationPolicy):
    name = "area-spread"
    description = "NRC's spread heuristic on the hashed grid ([VTT24] Sec. 6 baseline)"
    serves = frozenset({"grid"})
    Params = AreaSpreadParams

    def continuation(self, query: TerminationQuery) -> tuple[Any, Any]:
        stop = spread_stop(query, TerminationSettings(self.params.c))
        return weight_of(stop), query.state
