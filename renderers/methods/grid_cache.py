"""`grid-cache`: path tracing terminated into a hashed-grid radiance cache with three
moments by a variance-trading policy ([VTT24]; docs/variance_trading.md).

Every frame first runs the cache's propagation pass (timed as the stage
``propagation``: the path tracer's share of exploration, each pixel's first hit kept
as a representative with the config's ``primary_store_probability``, then
renderers/integrators/grid_update.py over every representative; frozen where freezing
is on, :class:`Propagation`), then renders with
the core asking the policy at every vertex (``render``; renderers/integrators/
grid_cache.py). Static scenes are pre-filled to equilibrium first (the paper fills
and propagates "until it reaches an equilibrium state", Sec. 6; :func:`prefill`): with
a short history, until the grid's mean stops changing, then the long history restarts
from there. The pre-fill does not depend on the policy (its seeds leave the policy's
parameters out), so renders that differ only in their policy reuse one pre-fill per
seed within :func:`prefills_shared` (:func:`prefilled`).

The policies (``termination``, with their own ``termination_params``): `var-bound`
(threshold t, absolute or relative), `mse-min` (sample target s, margin, clamp) and
`area-spread` (c). The cache's configuration is a typed
:class:`~renderers.caches.grid_config.MomentGridConfig` (``cache``: overrides; the
cell edge is ``cell_fraction`` of the scene's largest extent unless ``cache`` sets
``cell_size``), stored with the run as ``method_stats['caches']['cache']``. The
Russian-roulette survival probability (``rr_survival``, with ``rr_depth``) is stated
in every result's path statistics: bias and path length depend on it (Sec. 6).

Diffuse scenes only: a record holds reflected radiance without an outgoing direction,
as in the paper (Sec. 6), so scenes with glossy or delta BSDFs are refused.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, Literal

from pydantic import Field

from renderers.frozen import Frozen, freezing, padded, weak_method
from renderers.integrators.termination import policy_names, termination_params_type
from renderers.methods import register
from renderers.methods.base import (
    ComparisonRun,
    FrameHooks,
    Method,
    RenderOutput,
    WithParts,
    render_stage,
    run_frames,
)
from renderers.methods.cached import TerminationChoice, termination_params_field
from renderers.methods.pt import PTParams
from renderers.seeding import derive_seed, digest

#: The policies that serve the moment grid (the registry's).
GridTermination = Literal[policy_names("grid")]  # type: ignore[valid-type]
GridTerminationParams = termination_params_type("grid")

GRID_AOVS = ("depth", "cache_depth", "cache_vertices", "weighted_length")


#: Where this method's grid differs from MomentGridConfig's (the paper's) defaults,
#: sized for a CPU at small resolutions (docs/variance_trading.md): 8 samples per
#: vertex instead of 32 and 2 representatives per record instead of 4 keep a
#: propagation pass near a render pass; primary vertices are kept with 10 % instead of
#: 1 % because a 64x64 frame has 500 times fewer pixels than the paper's 1080p.
GRID_DEFAULTS: dict[str, Any] = {"samples_per_vertex": 8, "vertices_per_record": 2,
                                 "primary_store_probability": 0.1}

#: Named grid configurations (``cache={"preset": NAME}``, applied before the other
#: overrides): ``cpu``, the default, is :data:`GRID_DEFAULTS`; ``paper`` is the paper's
#: own (Sec. 5: 4 representatives per record, 32 samples per U-statistic, 1 % of
#: primary hits stored), which multiplies the propagation pass's cost about eight
#: times (4 x the samples at 2 x the representatives).
GRID_PRESETS: dict[str, dict[str, Any]] = {
    "cpu": GRID_DEFAULTS,
    "paper": {"samples_per_vertex": 32, "vertices_per_record": 4,
              "primary_store_probability": 0.01},
}
DEFAULT_GRID_PRESET = "cpu"


def grid_config(cell_size: float = 1.0, preset: str = DEFAULT_GRID_PRESET,
                **overrides: Any) -> Any:
    """The typed grid configuration: the ``preset``'s values (:data:`GRID_PRESETS`),
    then ``overrides`` (a placeholder cell edge where the method derives it from the
    scene)."""
    from renderers.caches.grid_config import MomentGridConfig

    if preset not in GRID_PRESETS:
        raise ValueError(f"unknown cache preset {preset!r}; choose one of "
                         f"{sorted(GRID_PRESETS)}")
    unknown = set(overrides) - set(MomentGridConfig.model_fields)
    if unknown:
        raise ValueError(f"unknown cache config field(s) {sorted(unknown)}; valid fields "
                         f"are {sorted(MomentGridConfig.model_fields)} and 'preset'")
    return MomentGridConfig(**{**GRID_PRESETS[preset], "cell_size": cell_size, **overrides})


class GridCacheParams(PTParams, TerminationChoice):
    """Parameters of `grid-cache` (PT core included; module doc)."""

    termination: GridTermination = Field(
        "var-bound", description="termination policy (renderers/integrators/termination)")
    termination_params: GridTerminationParams = termination_params_field()
    cache: dict[str, Any] = Field(default_factory=dict,
                                  description="cache config overrides (MomentGridConfig), "
                                              "'preset' first ('cpu', the default, or "
                                              "'paper')")
    cell_fraction: float = Field(1 / 16, gt=0.0, le=1.0,
                                 description="cell edge / the scene's largest extent "
                                             "(unless cache.cell_size is given)")
    prefill_frames: int = Field(128, ge=0, le=100_000,
                                description="most pre-fill passes before the first frame")
    prefill_history: int = Field(2, ge=1, le=1_000_000,
                                 description="observations a record averages over in the "
                                             "pre-fill (then cache.max_history)")
    prefill_tolerance: float = Field(2e-3, gt=0.0, le=1.0,
                                     description="the pre-fill ends when the grid's mean "
                                                 "luminance changes by less than this, "
                                                 "relative, per pass")
    hit_store_probability: float = Field(0.02, ge=0.0, le=1.0,
                                         description="chance that a propagation sample's "
                                                     "hit becomes a representative")

    def cache_presets(self) -> dict[str, Any]:
        return {"cache": grid_config}

    def grid_preset(self) -> str:
        """The name of the grid preset the cache started from (:data:`GRID_PRESETS`)."""
        return str(self.cache.get("preset", DEFAULT_GRID_PRESET))

    def termination_settings(self) -> Any:
        """No grid policy reads ``sph_c`` (area-spread has its own c), which is not a
        parameter here: the caching methods' default stands in."""
        from renderers.integrators.termination import TerminationSettings
        from renderers.methods.cached import CacheTrainingParams

        return TerminationSettings(CacheTrainingParams.model_fields["sph_c"].default)

    def resolved_grid(self, scene: Any) -> Any:
        """The grid configuration of ``scene`` (a renderers.scenes scene): the parsed
        config (:meth:`cache_config`) with the cell edge ``cell_fraction`` of the
        scene's largest extent, unless the overrides set ``cell_size``."""
        config = self.cache_config()
        if "cell_size" in self.cache:
            return config
        extents = scene.scene.bbox().extents()
        cell = self.cell_fraction * max(float(extents[i]) for i in range(3))
        if not cell > 0.0:
            raise ValueError("the scene has no extent to size the grid's cells by "
                             "(set cache.cell_size)")
        return config.model_copy(update={"cell_size": cell})


def build(scene: Any, params: GridCacheParams, seed: int) -> tuple[Any, Any, Any]:
    """(render integrator, update integrator, grid) of a `grid-cache` render."""
    import mitsuba as mi

    from renderers.caches.moment_grid import MomentGrid
    from renderers.integrators import grid_cache, grid_update, register_plugins

    register_plugins()
    core = {"max_depth": params.max_depth, "rr_depth": params.rr_depth,
            "rr_mode": params.rr_mode, "rr_survival": params.rr_survival}
    grid = MomentGrid(params.resolved_grid(scene))
    integrator = mi.load_dict({"type": grid_cache.PLUGIN_NAME, **core})
    # The update pass samples as the path tracer does (its NEE, BSDF and light selection).
    updater = mi.load_dict({"type": grid_update.UPDATE_PLUGIN_NAME, **core})
    integrator.grid = updater.grid = grid
    integrator.policy = params.termination_policy()
    return integrator, updater, grid


class Propagation:
    """The propagation pass, called with a frame's seed: the render's share of
    exploration (each pixel's first hit kept as a representative with the config's
    ``primary_store_probability``), then the update of every representative
    (renderers/integrators/grid_update.py); returns the vertices updated.

    Frozen where freezing is on (renderers.frozen), as two calls that take the grid's
    arrays (:meth:`MomentGrid.arrays`) and return them, rebound afterwards: the store
    of first hits (one lane per pixel) and the update. The update's representatives
    are compacted and counted on the host between the two, and padded to a power of
    two (at least :data:`MIN_WIDTH`) with the extra lanes masked, so that its cost
    follows their number while it records once per power of two it reaches (the
    count only grows: a representative is never dropped); those recordings are
    counted as :attr:`growth_recordings`. Frozen and traced passes draw the same
    samples and give the same records (docs/timing.md, "Frozen frames")."""

    #: The narrowest padded update: below it a recording costs more than the lanes.
    MIN_WIDTH = 256

    def __init__(self, scene: Any, updater: Any, grid: Any, params: GridCacheParams,
                 frozen: bool | None = None) -> None:
        self.scene, self.updater, self.grid = scene.scene, updater, grid
        self.params = params
        frozen = (freezing() if frozen is None else frozen) and updater.frame_freezable()
        self._store = (Frozen(weak_method(self._store_pass), auto_opaque=False) if frozen
                       else self._store_pass)
        self._update = (Frozen(weak_method(self._update_pass), auto_opaque=False) if frozen
                        else self._update_pass)
        self.frozen = frozen
        self.widths: list[int] = []   # the padded widths of the update, in order
        self.growth_recordings = 0    # recordings of updates at a width not seen before
        # (width, kernel history on) of the updates so far: a frozen call records anew
        # under each flag (renderers.timing.kernel_history), so a width is new per flag.
        self._met: set[tuple[int, bool]] = set()
        self._last_seed: int | None = None

    def __call__(self, seed: int, history: int | None = None) -> int:
        """One pass; ``history``: the records' averaging window (default the config's
        ``max_history``)."""
        import drjit as dr
        import mitsuba as mi

        from renderers.timing import kernel_history_enabled

        self._last_seed = seed
        grid, scene = self.grid, self.scene
        history = grid.config.max_history if history is None else history
        grid.bind(self._store(scene, grid.arrays(),
                              dr.opaque(mi.UInt32, derive_seed(seed, "store"))))
        place = grid.places()
        vertices = dr.width(place)   # the host read, outside the frozen calls
        if vertices == 0:
            return 0
        width = self.padded_width(vertices) if self.frozen else vertices
        if width not in self.widths:
            self.widths.append(width)
        met = (width, kernel_history_enabled())
        grown = met not in self._met
        self._met.add(met)
        before = self.recordings()
        state = self.updater.frame_state(scene)
        grid.bind(self._update(scene, grid.arrays(), state, padded(place, width),
                               dr.opaque(mi.UInt32, vertices),
                               dr.opaque(mi.UInt32, derive_seed(seed, "update")),
                               dr.opaque(mi.Float, history)))
        self.updater.bind_frame_state(scene, state)   # a recording bound its own inputs
        if grown and before is not None:
            self.growth_recordings += self.recordings() - before
        return vertices

    def padded_width(self, vertices: int) -> int:
        """The width the update of ``vertices`` representatives is padded to."""
        width = max(1 << (vertices - 1).bit_length(), self.MIN_WIDTH)
        return max(min(width, self.grid.most_places()), vertices)

    def recordings(self) -> int | None:
        """Recordings of the frozen calls (None when the pass is traced)."""
        if not self.frozen:
            return None
        return self._store.recordings() + self._update.recordings()  # type: ignore[union-attr]

    def settle(self) -> None:
        """The last pass again with the next seed, on a copy of the grid, dropped: a
        frozen call's key also holds what a render changes in the scene (its film),
        so the warm-up settles the pass's recordings after a render as the render's
        own (renderers.methods.base.WithParts, ``counted``). A replay writes its
        scatters into the arrays it is handed, hence the copy."""
        if self._last_seed is None:
            return
        held, seed = self.grid.arrays(), self._last_seed
        self.grid.bind(self.grid.copied_arrays())
        try:
            self(seed + 1)
        finally:
            self.grid.bind(held)
            self._last_seed = seed

    def _store_pass(self, scene: Any, arrays: dict[str, Any], seed: Any) -> dict[str, Any]:
        from renderers.integrators.grid_update import store_primary_vertices

        self.grid.bind(arrays)
        store_primary_vertices(scene, self.grid, scene.sensors()[0], seed,
                               self.grid.config.primary_store_probability)
        return self.grid.arrays()

    def _update_pass(self, scene: Any, arrays: dict[str, Any], state: dict[str, Any],
                     place: Any, vertices: Any, seed: Any, history: Any) -> dict[str, Any]:
        from renderers.integrators.grid_update import update_places

        self.grid.bind(arrays)
        self.updater.bind_frame_state(scene, state)
        update_places(scene, self.updater, place, vertices, seed,
                      self.params.hit_store_probability, history)
        return self.grid.arrays()


def propagate(scene: Any, updater: Any, grid: Any, params: GridCacheParams, seed: int) -> int:
    """One traced propagation pass (:class:`Propagation`); returns the vertices updated."""
    return Propagation(scene, updater, grid, params, frozen=False)(seed)


#: Passes over which the pre-fill measures the change of the grid's mean and record
#: count (a slope over several passes, so that one pass's noise does not end it early).
PREFILL_SPAN = 4


def prefill_settled(series: list[float], tolerance: float) -> bool:
    """Whether ``series`` (one value per pre-fill pass), averaged over the last
    :data:`PREFILL_SPAN` passes, is above 0 and moved by at most ``tolerance`` (relative)
    per pass from its average over the :data:`PREFILL_SPAN` passes before. Averages of
    windows, not single passes: a single pass's noise exceeds the tolerance on small
    grids (so each pass's change of the mean never met it, and the pre-fill always ran to
    its limit), and two passes :data:`PREFILL_SPAN` apart can meet it while the mean
    still moves (cornell-box 32x32 with 16 passes at most: 2 seeds of 16 stopped after 5
    and 6 passes, far from equilibrium, with 1.4-2.2x the other seeds' MRSE). A value of
    0 has not settled: for the mean, no light has reached the records yet (corridor
    32x32, lit at its far end: the first 4-8 passes' means are 0 on some seeds, and 0
    moved by 0 met the relative tolerance)."""
    recent = sum(series[-PREFILL_SPAN:]) / PREFILL_SPAN
    before = sum(series[-2 * PREFILL_SPAN:-PREFILL_SPAN]) / PREFILL_SPAN
    return recent > 0.0 and abs(recent - before) / PREFILL_SPAN <= tolerance * recent


def prefill_equilibrium(means: list[float], records: list[float], tolerance: float) -> bool:
    """Whether the pre-fill has reached equilibrium after these passes: the grid's mean
    luminance and its number of records have both settled (:func:`prefill_settled`).
    The mean alone has early flat stretches while exploration still adds records (door
    32x32: 4 pre-fills of 64 stopped after 8-16 passes with a few hundred of the ~900
    records a settled grid holds); the new records then enter the mean later."""
    return (len(means) >= 2 * PREFILL_SPAN and prefill_settled(means, tolerance)
            and prefill_settled(records, tolerance))


def prefill(propagation: Propagation, params: GridCacheParams,
            seed_parts: tuple[Any, ...]) -> tuple[int, list[float]]:
    """Pre-fill the grid to equilibrium ([VTT24] Sec. 6: "fill and propagate the radiance
    cache in a preprocess until it reaches an equilibrium state").

    Each pass propagates one bounce, so the records solve the rendering equation by a
    fixed-point iteration. Averaged over every pass since the start (the long history)
    a record's value lags that iteration, converging like t^-(1 - albedo); with a short
    window (``prefill_history`` observations, an exponential average over the last
    few passes) the iteration converges geometrically. Passes run until the grid's
    mean luminance and its number of records, each averaged over the last
    :data:`PREFILL_SPAN` passes, move by less than ``prefill_tolerance`` (relative) per
    pass from the window before (:func:`prefill_equilibrium`), at most
    ``prefill_frames``; then the long history restarts from the records' values
    (:meth:`MomentGrid.restart_history`), so the averages that follow are taken at
    equilibrium. Returns (passes taken, the grid's mean luminance after each)."""
    grid = propagation.grid
    means: list[float] = []
    records: list[float] = []
    for index in range(params.prefill_frames):
        propagation(derive_seed(*seed_parts, "prefill", index), params.prefill_history)
        means.append(grid.mean_luminance())
        records.append(float(grid.records()))
        if prefill_equilibrium(means, records, params.prefill_tolerance):
            break
    grid.restart_history()
    return len(means), means


#: The policy's parameters: the only ones the propagation pass never reads (the update
#: integrator samples as the path tracer does; the policy sits in the render integrator).
POLICY_FIELDS = frozenset({"termination", "termination_params"})
#: Pre-filled grids kept for reuse within :func:`prefills_shared` (:func:`prefilled`):
#: K seeds of a few scenes (a figure sweeps policies over one scene's K seeds).
PREFILLS_KEPT = 16
#: The kept grids, oldest first; None outside :func:`prefills_shared`.
_PREFILLS: OrderedDict[str, tuple[dict[str, Any], int]] | None = None


@contextmanager
def prefills_shared() -> Iterator[None]:
    """Within: renders keep their pre-filled grids and reuse them (:func:`prefilled`);
    on leaving, the grids are dropped. For a caller that renders scenes as loaded under
    several policies (a reproduced figure): a scene changed in place after loading keeps
    its fingerprint, so outside such a caller nothing is kept."""
    global _PREFILLS
    outer = _PREFILLS
    _PREFILLS = OrderedDict() if outer is None else outer
    try:
        yield
    finally:
        _PREFILLS = outer


def prefill_seed_parts(params: GridCacheParams, seed_parts: tuple[Any, ...]
                       ) -> tuple[Any, ...]:
    """The pre-fill's seed parts: the render's, with its parameters (as the executors
    put them in, ``model_dump(mode="json")``) less the policy's (:data:`POLICY_FIELDS`),
    so that renders differing only in their policy pre-fill alike."""
    full = params.model_dump(mode="json")
    shared = {name: value for name, value in full.items() if name not in POLICY_FIELDS}
    return tuple(shared if part == full else part for part in seed_parts)


def prefilled(scene: Any, propagation: Propagation, params: GridCacheParams,
              seed_parts: tuple[Any, ...]) -> tuple[int, bool]:
    """Pre-fill ``propagation``'s grid (:func:`prefill`, with
    :func:`prefill_seed_parts`), or, within :func:`prefills_shared`, give it a copy of
    the grid an earlier render there pre-filled from the same scene content, resolution,
    parameters but the policy's, and seeds: the pre-fill's records do not depend on the
    policy, and a pass gives the same bits per seed (version 4). Returns (passes,
    whether reused). An animated scene, or one without a fingerprint, is pre-filled anew
    (an animated scene's state when a render starts is not keyed)."""
    parts = prefill_seed_parts(params, seed_parts)
    grid, kept = propagation.grid, _PREFILLS
    fingerprint = getattr(scene, "fingerprint", None)
    key = (None if kept is None or fingerprint is None
           or getattr(scene, "animation", None) is not None else
           digest("grid-prefill", fingerprint, list(scene.resolution), parts))
    if kept is not None and key in kept:
        arrays, passes = kept[key]
        kept.move_to_end(key)
        grid.bind(arrays)
        grid.bind(grid.copied_arrays())   # a replay writes into the arrays it is handed
        return passes, True
    passes, _means = prefill(propagation, params, parts)
    if kept is not None and key is not None:
        kept[key] = (grid.copied_arrays(), passes)
        while len(kept) > PREFILLS_KEPT:
            kept.popitem(last=False)
    return passes, False


def render(scene: Any, params: GridCacheParams, *, seed_parts: tuple[Any, ...], spp: int,
           frames: int, hooks: FrameHooks = FrameHooks()) -> RenderOutput:
    """Pre-fill (or reuse a pre-fill, :func:`prefilled`), then per frame: a propagation
    pass, then the render pass (frozen where freezing is on)."""
    from renderers.timing import kernel_history, synchronize

    integrator, updater, grid = build(scene, params, derive_seed(*seed_parts, "cache"))
    propagate = Propagation(scene, updater, grid, params)
    start = time.perf_counter()
    # Read by no timer: the history off, as in the wall frames (a frozen pass records
    # anew under the other flag; the frames' warm-up settles both).
    with kernel_history(False):
        prefill_passes, prefill_reused = prefilled(scene, propagate, params, seed_parts)
    prefill_s = time.perf_counter() - start
    prefill_recordings = propagate.recordings()
    updated: list[int] = []
    render_only = render_stage(scene, integrator, spp)

    def frame(index: int, seed: int, timer: Any) -> Any:
        with timer.stage("propagation"):
            vertices = propagate(derive_seed(seed, "propagate"))
            synchronize(grid.keys)   # and the pass's pending stores, not in the render's time
        if index >= 0:
            updated.append(vertices)
        return render_only(index, seed, timer)

    # The pass's recordings count with the frame's (its width growth as growth).
    output = run_frames(WithParts(frame, render_only, counted=(propagate,)),
                        seed_parts=seed_parts, frames=frames, spp=spp, aov_names=GRID_AOVS,
                        hooks=hooks)
    output.path_stats.update(rr_survival=params.rr_survival, rr_depth=params.rr_depth,
                             rr_mode=params.rr_mode)
    output.method_stats = {
        "prefill_frames": params.prefill_frames, "prefill_passes": prefill_passes,
        "prefill_s": prefill_s, "prefill_reused": prefill_reused,
        "rr_survival": params.rr_survival,
        "grid_records": grid.records(),
        "updated_vertices_per_frame": sum(updated) / max(len(updated), 1),
        # The frozen pass's recordings in the pre-fill (None: traced) and the widths its
        # update was padded to.
        "propagation_frozen": None if prefill_recordings is None else {
            "recordings_after_prefill": prefill_recordings, "widths": propagate.widths},
        "caches": {"cache": {"preset": params.grid_preset(),
                             "config": grid.config.model_dump(mode="json"),
                            "per_frame": {"propagation_passes": 1,
                                          "samples_per_vertex":
                                              grid.config.samples_per_vertex}}},
    }
    return output


def diffuse_only(features: Any) -> tuple[bool, str]:
    """The paper's scenes are diffuse only (Sec. 6): a record holds reflected radiance
    without an outgoing direction, which a glossy or delta BSDF would need. An animation
    that moves shapes is refused: the cell edge is sized once from the scene's extent as
    loaded (:meth:`GridCacheParams.cache_config`), which moving shapes change."""
    if "shapes" in features.animation_changes:
        return False, ("the animation moves shapes: the grid's cell edge is sized from the "
                       "scene's extent as loaded, and a scene update does not size it again")
    if features.shape_count == 0:
        return False, "the scene has no surface for the cache to live on"
    if features.has_glossy or features.has_delta:
        kind = "glossy" if features.has_glossy else "delta"
        return False, (f"the scene has {kind} BSDFs; the grid cache holds reflected "
                       "radiance without direction, for diffuse surfaces only ([VTT24] "
                       "Sec. 6)")
    return True, ""


METHOD = register(Method(
    "grid-cache", "hashed-grid radiance cache with three moments, variance-trading "
    "termination", GridCacheParams, render, version=5, requires=diffuse_only, build=build,
    label="Grid cache", unbiased=False,
    # In the method comparison and the Pareto plot: its default policy (var-bound,
    # absolute t = 0.1), with PT matched to its frame time.
    comparison=(ComparisonRun(5, "Grid cache", "Grid cache (var-bound)", role="matched"),),
    stage_sizes=lambda _params, _pixels, _spp: {"propagation": 1.0}))
