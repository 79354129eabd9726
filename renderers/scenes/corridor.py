"""`corridor`: a winding corridor whose light is reachable only after several bounces.

The corridor is laid out on a grid of square cells (a path of cells, each
adjacent to the previous one); walls are generated wherever a corridor cell
borders a non-corridor cell, so the layout below is the whole definition.
The camera looks down the first leg towards its first turn (a short dead end
past the turn keeps the turn visible); the light panel is on the ceiling of
the last leg, around two corners. Light therefore reaches what the camera sees
only after three or more diffuse bounces, which makes short paths (and caches
that terminate early) visibly wrong and path tracing noisy.
"""

from __future__ import annotations

from renderers.scenes.parts import SceneDict, area_light, diffuse, quad, sensor, two_sided

CELL = 1.6  # width of a corridor cell (m)
HEIGHT = 2.6  # ceiling height (m)

#: Corridor cells as (column, row); column grows along +x, row along -z.
#: Leg 1 runs away from the camera, leg 2 turns right, leg 3 turns left again.
LAYOUT: tuple[tuple[int, int], ...] = (
    (0, 0), (0, 1), (0, 2), (0, 3),  # leg 1 (camera)
    (0, 4),  # a dead end past the first turn: its walls set the turn apart
    (1, 3), (2, 3), (3, 3),  # leg 2
    (3, 4), (3, 5),  # leg 3 (light)
)
LIGHT_CELL = (3, 5)

# The four neighbours of a cell with the wall each missing neighbour implies:
# (d_col, d_row) -> offset of the wall centre from the cell centre (x, z) and
# the two half-edge vectors (u, v) with u x v pointing into the cell.
_SIDES = {
    (1, 0): ((0.5, 0.0), (0, 0, 1), (0, 1, 0)),  # wall at +x, facing -x
    (-1, 0): ((-0.5, 0.0), (0, 1, 0), (0, 0, 1)),  # wall at -x, facing +x
    (0, 1): ((0.0, -0.5), (1, 0, 0), (0, 1, 0)),  # wall at -z (row + 1), facing +z
    (0, -1): ((0.0, 0.5), (0, 1, 0), (1, 0, 0)),  # wall at +z (row - 1), facing -z
}


def _cell_center(col: int, row: int) -> tuple[float, float]:
    return col * CELL, -row * CELL


def _walls(cells: set[tuple[int, int]], bsdf: SceneDict) -> dict[str, SceneDict]:
    shapes: dict[str, SceneDict] = {}
    half, half_h = CELL / 2, HEIGHT / 2
    for col, row in sorted(cells):
        cx, cz = _cell_center(col, row)
        # Floor and ceiling per cell keep every piece the same small size.
        shapes[f"floor-{col}-{row}"] = quad((cx, 0, cz), (0, 0, half), (half, 0, 0), bsdf)
        shapes[f"ceiling-{col}-{row}"] = quad((cx, HEIGHT, cz), (half, 0, 0), (0, 0, half), bsdf)
        for (dc, dr), ((ox, oz), u, v) in _SIDES.items():
            if (col + dc, row + dr) in cells:
                continue
            # Scale the unit directions to the wall's half extents.
            scale = {0: half, 1: half_h, 2: half}
            u_ = [c * scale[i] for i, c in enumerate(u)]
            v_ = [c * scale[i] for i, c in enumerate(v)]
            center = (cx + ox * CELL, half_h, cz + oz * CELL)
            shapes[f"wall-{col}-{row}-{dc}{dr}"] = quad(center, u_, v_, bsdf)
    return shapes


def corridor() -> SceneDict:
    """The corridor of LAYOUT with one light in LIGHT_CELL (see the module docstring)."""
    cells = set(LAYOUT)
    scene: SceneDict = {"type": "scene"}
    scene.update(_walls(cells, two_sided(diffuse((0.8, 0.78, 0.74)))))
    # A darker floor makes the turns legible (floor/wall edges show the layout).
    for col, row in cells:
        scene[f"floor-{col}-{row}"]["bsdf"] = two_sided(diffuse((0.5, 0.42, 0.35)))

    lx, lz = _cell_center(*LIGHT_CELL)
    # Large and very bright: the camera's leg only gets what survives three
    # or more diffuse bounces.
    scene["light"] = quad(
        (lx, HEIGHT - 0.01, lz), (0.7, 0, 0), (0, 0, 0.7), emitter=area_light((400.0, 370.0, 320.0))
    )
    # From the left of the first cell, aimed at the turn into leg 2 so that the
    # lit end wall and a glimpse of leg 2 are both in view.
    turn_x, turn_z = _cell_center(*LAYOUT[3])
    scene["sensor"] = sensor(
        origin=(-0.4, 1.6, 0.4), target=(turn_x + 0.5, 1.0, turn_z), fov=55
    )
    return scene
