"""The adversarial scenes of the stress suite (``nirc-bench stress``, docs/stress.md).

Each builder returns a :class:`StressScene`: Mitsuba XML text and the files it
reads (an environment map, a mesh), written next to each other into a folder,
so the same bytes are loaded by an embedded run and uploaded to a service
(``POST /api/v1/scenes``) by a remote one. Most scenes are variations of one
small room (:func:`room`): five diffuse walls seen from inside through the
open sixth side, a box on the floor, and the emitters and materials the case
is about. The film size is a placeholder; every render sets its own.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from metrics.imageio import write_exr

#: Diffuse grey of the walls.
GREY = '<bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.6, 0.6"/></bsdf>'


@dataclass(frozen=True)
class StressScene:
    """A scene's XML and the files it reads (relative name -> bytes)."""

    xml: str
    files: dict[str, bytes] = field(default_factory=dict)

    def write(self, folder: Path) -> Path:
        """Write the scene into ``folder`` (created); the path of its XML."""
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in self.files.items():
            (folder / name).write_bytes(data)
        path = folder / "scene.xml"
        path.write_text(self.xml)
        return path


def _sensor(origin: tuple[float, float, float], target: tuple[float, float, float],
            fov: float = 45.0, scale: float = 1.0) -> str:
    def text(v: tuple[float, float, float]) -> str:
        return ", ".join(f"{x:.9g}" for x in v)

    return f"""<sensor type="perspective">
        <float name="fov" value="{fov}"/>
        <float name="near_clip" value="{0.01 * scale:.9g}"/>
        <float name="far_clip" value="{1e3 * scale:.9g}"/>
        <transform name="to_world"><lookat origin="{text(origin)}" target="{text(target)}" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
            <rfilter type="box"/></film>
        <sampler type="independent"/>
    </sensor>"""


def _rectangle(transform: str, bsdf: str = GREY, extra: str = "") -> str:
    return (f'<shape type="rectangle"><transform name="to_world">{transform}</transform>'
            f'{bsdf}{extra}</shape>')


def area_light(radiance: str, transform: str, shape: str = "rectangle") -> str:
    """An emitting ``shape`` (black BSDF) of ``radiance`` (Mitsuba text, e.g. '5, 5, 5')."""
    return (f'<shape type="{shape}"><transform name="to_world">{transform}</transform>'
            '<bsdf type="diffuse"><rgb name="reflectance" value="0, 0, 0"/></bsdf>'
            f'<emitter type="area"><rgb name="radiance" value="{radiance}"/></emitter></shape>')


#: The default ceiling light of the room: a 0.5 x 0.5 square just below the ceiling.
CEILING_LIGHT = area_light("10, 10, 10", '<scale value="0.25"/><rotate x="1" angle="90"/>'
                                         '<translate y="0.99"/>')


def room(emitters: str = CEILING_LIGHT, *, wall: str = GREY, box: str = GREY,
         scale: float = 1.0, extra: str = "") -> StressScene:
    """A 2 x 2 x 2 room (walls at +-1, open towards +z where the camera looks from),
    a box on the floor, ``emitters`` and ``extra`` shapes, all scaled by ``scale``."""
    s = f'<scale value="{scale:.9g}"/>'
    walls = [
        '<rotate x="1" angle="-90"/><translate y="-1"/>',   # floor
        '<rotate x="1" angle="90"/><translate y="1"/>',     # ceiling
        '<translate z="-1"/>',                              # back
        '<rotate y="1" angle="90"/><translate x="-1"/>',    # left
        '<rotate y="1" angle="-90"/><translate x="1"/>',    # right
    ]
    shapes = "\n".join(_rectangle(w + s, wall) for w in walls)
    cube = (f'<shape type="cube"><transform name="to_world"><scale value="0.3"/>'
            f'<rotate y="1" angle="20"/><translate x="0.3" y="-0.7" z="-0.2"/>{s}</transform>'
            f'{box}</shape>')
    scaled = emitters.replace("</transform>", s + "</transform>")
    extra = extra.replace("</transform>", s + "</transform>")
    return StressScene(f"""<scene version="3.0.0">
    {_sensor((0.0, 0.0, 3.6 * scale), (0.0, 0.0, 0.0), scale=scale)}
    {shapes}
    {cube}
    {scaled}
    {extra}
</scene>
""")


def fireflies() -> StressScene:
    """A dim ceiling light and a tiny (radius 0.005) very bright sphere light (radiance
    1e6 x the room's) behind the box: paths that find it are rare and huge."""
    tiny = area_light("1e6, 1e6, 1e6", '<scale value="0.005"/><translate x="0.6" y="-0.5" z="-0.6"/>',
                      shape="sphere")
    return room(area_light("1, 1, 1", '<scale value="0.25"/><rotate x="1" angle="90"/>'
                                      '<translate y="0.99"/>') + tiny)


def near_black() -> StressScene:
    """Black walls and a black box (reflectance 0 and 0.001): almost every pixel of
    the reference is 0 or nearly so, the relative metrics' eps is all that holds them."""
    black = '<bsdf type="diffuse"><rgb name="reflectance" value="0, 0, 0"/></bsdf>'
    dark = '<bsdf type="diffuse"><rgb name="reflectance" value="0.001, 0.001, 0.001"/></bsdf>'
    return room(wall=black, box=dark)


def near_mirror() -> StressScene:
    """Walls of rough conductor and a rough-plastic box with roughness 1e-4: glossy
    lobes that are almost delta peaks (BSDF values ~1e8)."""
    metal = ('<bsdf type="roughconductor"><string name="material" value="Al"/>'
             '<float name="alpha" value="0.0001"/></bsdf>')
    plastic = ('<bsdf type="roughplastic"><float name="alpha" value="0.0001"/>'
               '<rgb name="diffuse_reflectance" value="0.5, 0.2, 0.2"/></bsdf>')
    return room(wall=metal, box=plastic)


def grazing() -> StressScene:
    """A floor seen at 0.5 degrees above its plane, lit by a light 1 degree above it:
    cosines near 0 at the camera and at the light."""
    floor = _rectangle('<scale value="50"/><rotate x="1" angle="-90"/>')
    light = area_light("2000, 2000, 2000",
                       '<scale value="2"/><rotate y="1" angle="180"/><translate z="60" y="1"/>')
    return StressScene(f"""<scene version="3.0.0">
    {_sensor((0.0, 0.3, 35.0), (0.0, 0.0, 0.0), fov=20.0)}
    {floor}
    {light}
</scene>
""")


def _environment_map(width: int = 64, height: int = 32, peak: float = 1e5) -> bytes:
    """An equirectangular map of radiance 1 with a 2 x 2-texel sun of ``peak``: a
    dynamic range of ``peak``."""
    image = np.ones((height, width, 3), dtype=np.float32)
    image[height // 4:height // 4 + 2, width // 3:width // 3 + 2] = peak
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "env.exr"
        write_exr(path, image)
        return path.read_bytes()


def environment() -> StressScene:
    """A floor and a box lit only by an environment map with a 1e5 dynamic range."""
    return StressScene(f"""<scene version="3.0.0">
    {_sensor((0.0, 1.0, 3.6), (0.0, -0.5, 0.0))}
    {_rectangle('<scale value="3"/><rotate x="1" angle="-90"/><translate y="-1"/>')}
    <shape type="cube"><transform name="to_world"><scale value="0.4"/><translate y="-0.6"/></transform>{GREY}</shape>
    <emitter type="envmap"><string name="filename" value="env.exr"/></emitter>
</scene>
""", {"env.exr": _environment_map()})


def _degenerate_mesh() -> bytes:
    """An OBJ quad (two triangles) plus zero-area triangles: collinear vertices, a
    repeated vertex and all three vertices equal."""
    return b"""v -0.8 -0.8 0
v 0.8 -0.8 0
v 0.8 0.8 0
v -0.8 0.8 0
v 0 0 0
v 0.4 0.4 0
v 0.8 0.8 0
f 1 2 3
f 1 3 4
f 5 6 7
f 5 5 6
f 6 6 6
"""


def degenerate_triangles() -> StressScene:
    """The room with a mesh of zero-area triangles (collinear, repeated vertices) in
    front of the back wall, next to two valid ones."""
    mesh = ('<shape type="obj"><string name="filename" value="degenerate.obj"/>'
            '<transform name="to_world"><translate z="-0.5"/></transform>' + GREY + '</shape>')
    scene = room(extra=mesh)
    return StressScene(scene.xml, {"degenerate.obj": _degenerate_mesh()})


def radiance(value: str) -> Callable[[], StressScene]:
    """The room's ceiling light next to a second light of radiance ``value``."""
    def build() -> StressScene:
        return room(CEILING_LIGHT + area_light(
            value, '<scale value="0.15"/><rotate y="1" angle="90"/><translate x="-0.99" y="0.3"/>'))

    return build


def no_emitter() -> StressScene:
    """The room without any emitter: every pixel is 0."""
    return room("")


def closed_box() -> StressScene:
    """The camera inside a closed cube lit by a point light: no path escapes."""
    return StressScene("""<scene version="3.0.0">
    """ + _sensor((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), fov=60.0) + """
    <shape type="cube"><transform name="to_world"><scale value="2"/></transform>
        <bsdf type="twosided">""" + GREY + """</bsdf></shape>
    <emitter type="point"><point name="position" value="0.5, 0.5, 0.5"/>
        <rgb name="intensity" value="5, 5, 5"/></emitter>
</scene>
""")
