"""Configuration of the hashed-grid radiance cache with three moments
(:mod:`renderers.caches.moment_grid`); pydantic only, so the service can validate it
without a renderer."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class MomentGridConfig(BaseModel):
    """A spatial hash of positions whose records track E[Y], E[Y^2] and E[E[Y|y]^2]
    ([VTT24] Sec. 4.4 and 5; hashed grids after [BFK19]; docs/references.md).

    ========================  =====================================================
    ``cell_size``             edge of a grid cell, in scene units
    ``log2_table_size``       the hash table holds 2^k records
    ``max_probes``            linear-probing steps before a key gives up (a miss)
    ``normal_bins``           also key a cell by the normal's dominant axis and sign
                              (six bins, Binder et al.'s normal binning), so the two
                              sides of a thin wall do not share a record
    ``vertices_per_record``   representative vertices kept per record (the paper: 4)
    ``samples_per_vertex``    independent samples per vertex and update, paired all
                              with all for the marginal second moment (the paper: 32)
    ``max_history``           vertex estimates a record's running moments average
                              over; beyond it they become an exponential average, so
                              radiance that propagates over frames is followed (a
                              pre-fill averages over a shorter window first, then
                              restarts this history at equilibrium)
    ``jitter``                stochastic interpolation: the lookup position is
                              jittered by up to half a cell in the tangent plane
    ``primary_store_probability``  the path tracer stores a primary vertex as a
                              record's representative with this probability (1 %)
    ========================  =====================================================
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    cell_size: float = Field(gt=0.0)
    log2_table_size: int = Field(16, ge=4, le=24)
    max_probes: int = Field(8, ge=1, le=64)
    normal_bins: bool = True
    vertices_per_record: int = Field(4, ge=1, le=16)
    samples_per_vertex: int = Field(32, ge=2, le=1024)
    max_history: int = Field(4096, ge=1)
    jitter: bool = True
    primary_store_probability: float = Field(0.01, ge=0.0, le=1.0)

    @property
    def table_size(self) -> int:
        return 1 << self.log2_table_size
