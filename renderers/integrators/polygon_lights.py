"""The unshadowed direct light of polygonal area emitters, in closed form.

For a planar polygon P of uniform radiance L_e and a shading point x with
normal n, the integral of the cosine over the solid angle P subtends (its
projected solid angle; Lambert 1760, in the vector form of Arvo,
"Applications of irradiance tensors to the simulation of non-Lambertian
phenomena", SIGGRAPH 1995) is a sum over P's edges:

    E(x) = ∫_P max(cos θ_x, 0) dω = | n · Φ |,   Φ = 1/2 Σ_i Θ_i γ_i

with a_i = v_i - x, Θ_i = angle(a_i, a_{i+1}) = atan2(|a_i × a_{i+1}|, a_i · a_{i+1})
and γ_i = (a_i × a_{i+1}) / |a_i × a_{i+1}|. Φ is the polygon's vector
irradiance (per unit radiance). The formula holds for the part of P above
x's tangent plane: every edge is first clipped to n · a >= 0. The edge the
clip adds along the horizon lies in the tangent plane, so its γ is
perpendicular to n and it adds nothing to E; it is added to Φ only for the
direction below. For a Lambertian BSDF of albedo ρ the reflected direct light
of emitter k, unshadowed, is then exact:

    U_k(x) = ρ / π · L_e,k · Σ_{triangles t of k, x in front of t} E_t(x)

(x "in front": on the side of t's face normal, the side a one-sided area
emitter emits to). For any other BSDF f the factor ρ / π becomes
f(x, ω_o, ω_k) / cos θ_k evaluated at one direction, ω_k = Φ_k / |Φ_k| (the
irradiance-weighted mean direction of the visible part of the light): exact
for a diffuse f (constant over directions), an approximation for a glossy
one, whose lobe varies over the light (the Neural Visibility Cache paper uses
linearly transformed cosines there, Sec. 3.1). Delta lobes get 0.

Emitters: area emitters on meshes (a Mitsuba ``rectangle`` is a two-triangle
mesh; ``obj``/``ply`` meshes work), planar triangles with their face normal,
uniform radiance (the ``radiance.value`` of a constant texture).

Cost: the sum runs as symbolic loops over the emitters and their triangles
(gathering vertices from a buffer), so the kernel's size does not grow with
the number of lights: one BSDF evaluation per light and shading point, a few
dozen flops per triangle edge.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np


class PolygonLights:
    """The scene's emitters as triangles with a uniform radiance each (module docstring).

    Raises ValueError, naming the emitter, for an emitter that is not a mesh
    (environment, point, sphere lights) and for a textured radiance.
    """

    def __init__(self, scene: mi.Scene) -> None:
        self.scene = scene
        triangles: list[np.ndarray] = []   # per emitter: (T, 3, 3) world-space vertices
        radiance: list[np.ndarray] = []
        # The shapes as their own classes (emitter.get_shape() gives the base class).
        owners = {id(shape.emitter()): shape for shape in scene.shapes()
                  if shape.emitter() is not None}
        for index, emitter in enumerate(scene.emitters()):
            shape = owners.get(id(emitter))
            if shape is None or not isinstance(shape, mi.Mesh):
                raise ValueError(f"emitter {index} ({emitter.id() or type(emitter).__name__}) is "
                                 "not a polygon: only area emitters on meshes (rectangles, "
                                 "triangle meshes) have a closed-form unshadowed term")
            params = mi.traverse(emitter)
            if "radiance.value" not in params:
                raise ValueError(f"emitter {index} ({emitter.id()}) has a textured radiance: "
                                 "the closed form needs a uniform one")
            radiance.append(np.asarray(params["radiance.value"], dtype=np.float32).reshape(-1))
            positions = np.asarray(shape.vertex_positions_buffer(), dtype=np.float64)
            faces = np.asarray(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)
            triangles.append(positions.reshape(-1, 3)[faces])
        self.count = len(triangles)
        # Flat buffers: triangle t of emitter k is t in [first[k], first[k + 1]).
        flat = np.concatenate(triangles) if triangles else np.zeros((0, 3, 3))
        self.first = mi.UInt32(np.cumsum([0] + [len(t) for t in triangles]))
        self.vertices = [mi.Point3f(*(mi.Float(flat[:, j, c]) for c in range(3)))
                         for j in range(3)]
        rgb = np.stack(radiance) if radiance else np.zeros((0, 3))
        self.radiance = mi.Color3f(*(mi.Float(rgb[:, c]) for c in range(3)))

    def frame_arrays(self) -> dict[str, Any]:
        """The Dr.Jit data :meth:`shade` reads: a frozen frame takes it as an argument
        (renderers.frozen: a recording may only read Dr.Jit values it was given)."""
        return {"first": self.first, "vertices": self.vertices, "radiance": self.radiance}

    def bind(self, arrays: dict[str, Any]) -> None:
        self.first, self.vertices, self.radiance = (
            arrays["first"], arrays["vertices"], arrays["radiance"])

    @dr.syntax
    def shade(self, si: mi.SurfaceInteraction3f, visibility: list[mi.Float],
              active: mi.Bool) -> mi.Color3f:
        """Σ_k U_k(x) w_k(x): the unshadowed direct light of every emitter k toward
        si.wi (module docstring) weighted by ``visibility`` (one Float per emitter);
        0 where ``active`` is False."""
        if len(visibility) != self.count:
            raise ValueError(f"{len(visibility)} visibility values for {self.count} emitters")
        bsdf = si.bsdf()
        # The hemisphere light arrives from: the side of w_i (two-sided BSDFs).
        n = dr.mulsign(si.sh_frame.n, mi.Frame3f.cos_theta(si.wi))
        total = mi.Color3f(0)
        k = mi.UInt32(0)
        while active & (k < self.count):
            irradiance, vector = mi.Float(0), mi.Vector3f(0)
            t = dr.gather(mi.UInt32, self.first, k)
            end = dr.gather(mi.UInt32, self.first, k + 1)
            while t < end:
                v = [dr.gather(mi.Point3f, vertices, t) for vertices in self.vertices]
                e, phi = triangle_irradiance(si.p, n, v)
                irradiance += e
                vector += phi
                t += 1
            length = dr.norm(vector)
            live = irradiance > 0
            f = bsdf.eval(mi.BSDFContext(), si, si.to_local(vector / length), live)
            # f includes cos θ_k = n · Φ / |Φ| = E / |Φ|: f_r L E = f L |Φ|.
            weight = visibility[0]
            for index in range(1, self.count):
                weight = dr.select(k == index, visibility[index], weight)
            term = f * dr.gather(mi.Color3f, self.radiance, k) * (length * weight)
            total += dr.select(live, mi.Color3f(term), 0.0)
            k += 1
        return total


def edge_vector(a: mi.Vector3f, b: mi.Vector3f) -> mi.Vector3f:
    """Θ γ of the edge from a to b (points relative to x): the angle the edge
    subtends times the unit normal of the plane through x, a and b."""
    cross = dr.cross(a, b)
    length = dr.norm(cross)
    theta = dr.atan2(length, dr.dot(a, b))
    return dr.select(length > 0, cross * (theta / length), 0.0)


def triangle_irradiance(p: mi.Point3f, n: mi.Vector3f,
                        v: list[mi.Point3f]) -> tuple[mi.Float, mi.Vector3f]:
    """(E, Φ) of the emitting triangle with vertices ``v`` at points ``p`` with normals
    ``n``: 0 unless p is in front of it; edges clipped to the upper hemisphere of n."""
    in_front = dr.dot(p - v[0], dr.cross(v[1] - v[0], v[2] - v[0])) > 0
    phi = mi.Vector3f(0)
    exit_point, entry_point = mi.Vector3f(0), mi.Vector3f(0)
    for i in range(3):
        a, b = v[i] - p, v[(i + 1) % 3] - p
        ha, hb = dr.dot(n, a), dr.dot(n, b)
        # The crossing of the tangent plane, where the edge has one: a + t (b - a).
        crossing = dr.fma(b - a, ha / (ha - hb), a)
        leaving, entering = (ha >= 0) & (hb < 0), (ha < 0) & (hb >= 0)
        start = dr.select(entering, crossing, a)
        end = dr.select(leaving, crossing, b)
        phi += dr.select((ha >= 0) | (hb >= 0), edge_vector(start, end), 0.0)
        exit_point = dr.select(leaving, crossing, exit_point)
        entry_point = dr.select(entering, crossing, entry_point)
    # The clipped polygon's edge along the horizon, from where it leaves to where it
    # re-enters: nothing to E (its γ is horizontal), part of Φ's direction.
    phi += edge_vector(exit_point, entry_point)
    phi = 0.5 * phi
    # The winding of the triangle as seen from p fixes Φ's sign: turn it up.
    e = dr.dot(n, phi)
    phi = dr.mulsign(phi, e)
    return dr.select(in_front, dr.abs(e), 0.0), dr.select(in_front, phi, 0.0)
