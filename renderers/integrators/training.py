"""Training paths: the PT core with recording hooks, producing cache training records.

Training paths are traced by a separate launch from the render paths (NIRC
paper Sec. 4.5: a few % of the pixel count), starting at uniformly random
pixels, with the same core, Russian roulette and ``max_depth`` as the render
paths (default unbounded). Counted from the camera like a render path, a
record at x_j then has exactly the depth budget a render path terminating
into the cache at x_j had left; docs/training.md states what still differs.
At each of the first ``D``
vertices x_j of a path we record the cache inputs at x_j and the direction w_j
the path continued in; when the path arrives at x_{j+1} we record the radiance
accumulated so far *including* x_{j+1}'s MIS-weighted emission, L_j, and the
throughput at arrival, beta_{j+1}. Everything the path collects after that is
light reflected at x_{j+1} toward x_j, so after the path ends

    target_j = (L_final - L_j) / beta_{j+1}

is a one-sample, unbiased estimate of the indirect incident radiance
L_ind(x_j, w_j) (Eq. 8: NEE at x_{j+1} plus everything further; not x_{j+1}'s
own emission). A direction that escapes the scene has target 0 (light from the
environment is direct light). Records whose path stopped before reaching
x_{j+1} (roulette, depth limit, absorbed sample) are invalid; a record whose
x_{j+1} is the last vertex ``max_depth`` allows is valid with target 0 (a
render path at that depth gets no indirect light there either).

The same quantity is the radiance *reflected at x_{j+1} toward x_j*, which is
what NRC caches: with ``key_vertex='arrival'`` record j holds the inputs of
x_j itself (from the primary hit x_0 on) with direction w_o = -w_{j-1}, and
the target is divided by NRC's albedo demodulation factor at x_j (misses are
invalid: there is no surface).
NIRC records use ``key_vertex='departure'`` (inputs of x_j, direction w_j).

The variance-based loss L_V (NIRC paper Eq. 16) needs the residual's
expectation F_r at each record's shading point, estimated from several samples
there (Fig. 4). With ``paths_per_point`` K > 1 the paths come in groups of K
consecutive paths through one film position (one camera ray: the same first
vertex x_0 for a pinhole camera), each sampling its own directions from there;
the K records at x_0 (``record_depth`` 1) are the loss's group.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi

from renderers.frozen import Frozen, freezing, weak_method
from renderers.integrators import register
from renderers.integrators.cached import cache_inputs, demodulation
from renderers.integrators.path import PathIntegrator, Vertex, VertexTerms

RECORD_FIELDS = {
    "position": mi.Point3f, "normal": mi.Vector3f, "roughness": mi.Float,
    "albedo": mi.Color3f, "albedo_spec": mi.Color3f, "direction": mi.Vector3f,
    "L_before": mi.Color3f, "beta_arrival": mi.Color3f, "demodulation": mi.Color3f,
    "valid": mi.Bool,
}
#: The prefix of the training-path integrators' plugin names.
TRAINING_PLUGIN = "nirc_training"


@register
class TrainingPathIntegrator(PathIntegrator):
    """Records (inputs, direction, radiance prefix) at the first ``record_depth`` vertices.

    Properties: ``record_depth`` (default 3), ``key_vertex`` ('departure' for
    NIRC, 'arrival' for NRC; see the module docstring).
    """
    plugin_name = f"{TRAINING_PLUGIN}_trainingpathintegrator"

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.record_depth = int(props.get("record_depth", 3))
        self.key_vertex = str(props.get("key_vertex", "departure"))
        if self.key_vertex not in ("departure", "arrival"):
            raise ValueError("key_vertex must be 'departure' or 'arrival'")
        self.buffers: dict[str, Any] = {}
        self.n_paths = 0
        self.paths_per_point = 1   # set by configure
        # The records of a frame, frozen (renderers.frozen) where the frame can be: all
        # inputs opaque from the first call (the seed changes every frame).
        self._records_fn = (Frozen(weak_method(self._trace_records), auto_opaque=False)
                            if freezing() else None)
        self._last_call: tuple[Any, int, int] | None = None   # for settle()

    def configure(self, params: Any) -> None:
        """Take the method's validated parameters: plain training paths need only the
        records per shading point of the cache's loss (``paths_per_point``; a subclass
        may need more, e.g. NRC self-training)."""
        self.paths_per_point = params.cache_config().loss.records_per_point
        if self.paths_per_point > 1 and self.record_depth != 1:
            raise ValueError("a loss that takes several records per shading point (L_V) "
                             "trains on the first vertex only: set record_depth=1")

    def _slot(self, record: mi.UInt32) -> mi.UInt32:
        return self.path_index() * self.record_depth + record

    def arrival_slot(self, depth: mi.UInt32) -> mi.UInt32:
        """Record index of the vertex the path just arrived at (see the module docstring):
        departure records j are completed at x_{j+1}; arrival records j are x_j itself."""
        return depth - 1 if self.key_vertex == "departure" else depth

    def after_emission(self, vertex: Vertex, state: Any) -> Any:
        # Arrival: the prefix of radiance and the throughput (and, keyed at the
        # arrival vertex, its cache inputs) of the record this vertex completes.
        j = self.arrival_slot(vertex.depth)
        first = 1 if self.key_vertex == "departure" else 0
        ok = vertex.active & (vertex.depth >= first) & (j < self.record_depth)
        slot = self._slot(j)
        if self.key_vertex == "arrival":
            ok &= vertex.si.is_valid()
            inputs = cache_inputs(vertex.si, vertex.bsdf, specular=True)
            inputs["demodulation"] = demodulation(inputs)
            inputs["direction"] = -vertex.ray.d
            self._scatter(inputs, slot, ok)
        self._scatter({"L_before": vertex.L, "beta_arrival": vertex.beta, "valid": True},
                      slot, ok)
        # Cooperative: a subclass mixing in a caching integrator keeps its own state.
        return super().after_emission(vertex, state)

    def vertex_terms(self, vertex: Vertex, state: Any) -> tuple[VertexTerms | None, Any]:
        # Departure from x_j: the cache inputs and the sampled direction of record j.
        if self.key_vertex == "departure":
            ok = (vertex.active_next & (vertex.depth < self.record_depth)
                  & (vertex.bsdf_sample.pdf > 0))
            inputs = cache_inputs(vertex.si, vertex.bsdf)
            inputs["direction"] = vertex.si.to_world(vertex.bsdf_sample.wo)
            self._scatter(inputs, self._slot(vertex.depth), ok)
        return super().vertex_terms(vertex, state)

    def path_index(self) -> mi.UInt32:
        return dr.arange(mi.UInt32, self.n_paths)

    def _scatter(self, values: dict[str, Any], slot: mi.UInt32, active: mi.Bool) -> None:
        for name, value in values.items():
            dr.scatter(self.buffers[name], RECORD_FIELDS[name](value), slot, active)

    def trace_records(self, scene: mi.Scene, n_paths: int, seed: int) -> dict[str, Any]:
        """Trace ``n_paths`` training paths from random pixels; return the record arrays.
        Frozen where the frame can be (``frame_freezable``): the seed and what the paths
        read (``frame_state``) are the recording's arguments."""
        self._last_call = (scene, n_paths, seed)
        if self._records_fn is None or not self.frame_freezable():
            return self._trace_records(scene, mi.UInt32(seed), n_paths,
                                       self.frame_state(scene))
        state = self.frame_state(scene)
        try:
            return self._records_fn(scene, mi.UInt32(seed), n_paths, state)
        finally:
            self.bind_frame_state(scene, state)   # a recording bound its own inputs

    def recordings(self) -> int | None:
        """Recordings of the frozen records pass (None when it is not frozen)."""
        return self._records_fn.recordings() if self._records_fn is not None else None

    def settle(self) -> None:
        """Trace the last call's records again with another seed and drop them (a pure
        function of its arguments: nothing changes), so that its recordings settle in
        a warm-up."""
        if self._last_call is not None:
            scene, n_paths, seed = self._last_call
            dr.eval(self.trace_records(scene, n_paths, seed + 1))
            self._last_call = (scene, n_paths, seed)

    def _trace_records(self, scene: mi.Scene, seed: mi.UInt32, n_paths: int,
                       state: dict[str, Any]) -> dict[str, Any]:
        self.bind_frame_state(scene, state)
        sensor = scene.sensors()[0]
        group = self.paths_per_point
        n_paths = -(-n_paths // group) * group
        size = n_paths * self.record_depth
        self.n_paths = n_paths
        self.buffers = {name: dr.zeros(kind, size) for name, kind in RECORD_FIELDS.items()}
        # Departure records are never demodulated.
        self.buffers["demodulation"] = dr.full(mi.Color3f, 1.0, size)
        dr.eval(self.buffers)

        sampler = sensor.sampler().clone()
        sampler.seed(seed, n_paths)
        # A uniformly random film position per path (not a pixel grid): every
        # surface seen by the camera can be trained on; per group of paths with
        # paths_per_point > 1.
        camera_samples = (sampler.next_1d(), sampler.next_2d(), sampler.next_2d())
        if group > 1:
            first = dr.arange(mi.UInt32, n_paths) // group * group
            camera_samples = tuple(dr.gather(type(v), v, first) for v in camera_samples)
        ray, ray_weight = sensor.sample_ray(
            time=0.0, sample1=camera_samples[0], sample2=camera_samples[1],
            sample3=camera_samples[2])
        L, _, _, _ = self.trace(scene, sampler, ray)

        records = dict(self.buffers)
        path = dr.arange(mi.UInt32, size) // self.record_depth
        L_final = dr.gather(mi.Color3f, mi.Color3f(L), path)
        beta = records.pop("beta_arrival")
        target = (L_final - records.pop("L_before")) / (beta * records.pop("demodulation"))
        records["valid"] &= dr.all(beta > 0)
        records["target"] = dr.select(records["valid"], target, 0)
        if self.key_vertex == "departure":
            del records["albedo_spec"]
        dr.eval(records)
        return records


