"""XML pieces shared by the test scenes written inline."""

from __future__ import annotations


def perspective_sensor(fov: str, origin: str, target: str, *, res: str = "{res}") -> str:
    """A perspective sensor with a square box-filtered HDR film of ``res`` pixels and an
    independent sampler. Arguments are pasted as text, so a format field such as
    ``"{fov}"`` (or the default ``res``) stays a field of the scene template."""
    return f"""<sensor type="perspective">
        <float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="{origin}" target="{target}" up="0, 1, 0"/></transform>
        <film type="hdrfilm">
            <integer name="width" value="{res}"/><integer name="height" value="{res}"/>
            <rfilter type="box"/>
        </film>
        <sampler type="independent"/>
    </sensor>"""


#: A closed box (its BSDF: ``{bsdf}``, e.g. DIFFUSE) lit by a point light, seen from inside.
CLOSED_BOX = """<scene version="3.0.0">
    """ + perspective_sensor("60", "0, 0, 0", "0, 0, 1") + """
    <shape type="cube">
        <transform name="to_world"><scale value="2"/></transform>
        <bsdf type="twosided">{bsdf}</bsdf>
    </shape>
    <emitter type="point">
        <point name="position" value="0.5, 0.5, 0.5"/>
        <rgb name="intensity" value="5, 5, 5"/>
    </emitter>
</scene>
"""
DIFFUSE = '<bsdf type="diffuse"/>'
