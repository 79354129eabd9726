"""Animations: keyframed changes of a scene's parameters, applied frame by frame
(docs/animation.md).

An :class:`Animation` is plain, validated data (pydantic, strict, no NaN or
infinity): camera keys (position, target, up, field of view), rigid motions of
named shapes (a translation and a turn about an axis through a pivot, relative to
the shape's pose as loaded), step changes of named emitters' radiance (a
factor of the loaded radiance from a frame on; 0 switches an emitter off) and
disocclusions (frames at which every pixel's motion vector is invalid: a
renderer that reuses the previous frame's pixels starts that frame afresh, while
the image is the same).
Between two keys a value is interpolated linearly, or held until the later key
where that key is a ``step`` (a cut: the frame jumps).

:meth:`Animation.state` is what frame f shows; :meth:`Animation.state_key` names
it, so frames that show the same state share a reference. The change points
(:meth:`Animation.change_frames`) are the frames where the state jumps (emitter
changes and step keys) and the disocclusions; recovery times are measured after them.

:class:`AnimationPlayer` applies a frame's state to a loaded ``mi.Scene`` through
``mi.traverse`` and ``params.update()`` only: parameter values change, the
scene's layout (its shapes, emitters and their order) never does, so frozen
frames (renderers.frozen) keep replaying their recordings on the updated values.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from renderers.scenes.errors import SceneError
from renderers.seeding import digest

Vector3 = tuple[float, float, float]
#: Keys, motions or changes one animation may hold (a spec is data from users).
MAX_ITEMS = 1000
#: Frames an animation may reach (RenderSpec's frame limit).
MAX_FRAME = 100_000
#: Decimal places of a state's values in its key: equal states at float noise share one.
KEY_DECIMALS = 9


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=False, allow_inf_nan=False)


class CameraKey(_Strict):
    """The camera at ``frame``: where it is, what it looks at, its field of view."""

    frame: int = Field(ge=0, le=MAX_FRAME)
    position: Vector3
    target: Vector3
    up: Vector3 = (0.0, 1.0, 0.0)
    fov: float | None = Field(None, gt=0.0, lt=180.0, description="horizontal, degrees; "
                                                                 "None keeps the scene's")
    step: bool = False

    @model_validator(mode="after")
    def _well_posed(self) -> CameraKey:
        direction = np.subtract(self.target, self.position)
        if not np.linalg.norm(direction) > 0:
            raise ValueError(f"camera key at frame {self.frame}: target equals position")
        if not np.linalg.norm(np.cross(direction, self.up)) > 1e-9 * np.linalg.norm(direction):
            raise ValueError(f"camera key at frame {self.frame}: up is parallel to the "
                             "viewing direction (or zero)")
        return self


class ShapeKey(_Strict):
    """A shape's displacement at ``frame`` from its loaded pose."""

    frame: int = Field(ge=0, le=MAX_FRAME)
    translate: Vector3 = (0.0, 0.0, 0.0)
    angle_deg: float = Field(0.0, ge=-3600.0, le=3600.0)
    step: bool = False


class ShapeMotion(_Strict):
    """The rigid motion of the shape with id ``shape``: its keys, and the axis and pivot
    of their turns. The shape's ``to_world`` (or, for a mesh, its vertex positions) is
    the loaded one moved by T(translate) * R(axis, angle about pivot)."""

    shape: str = Field(min_length=1)
    axis: Vector3 = (0.0, 1.0, 0.0)
    pivot: Vector3 = (0.0, 0.0, 0.0)
    keys: list[ShapeKey] = Field(min_length=1, max_length=MAX_ITEMS)

    @field_validator("axis")
    @classmethod
    def _axis(cls, axis: Vector3) -> Vector3:
        if not np.linalg.norm(axis) > 0:
            raise ValueError("axis must not be zero")
        return axis

    @field_validator("keys")
    @classmethod
    def _ordered(cls, keys: list[ShapeKey]) -> list[ShapeKey]:
        return _increasing(keys, "shape keys")


class EmitterChange(_Strict):
    """From ``frame`` on, the emitter of the shape (or the emitter) with id ``emitter``
    has ``scale`` times its loaded radiance (0: off)."""

    emitter: str = Field(min_length=1)
    frame: int = Field(ge=0, le=MAX_FRAME)
    scale: float = Field(ge=0.0, le=1e6)


def _increasing(keys: list[Any], what: str) -> list[Any]:
    frames = [key.frame for key in keys]
    if any(b <= a for a, b in zip(frames, frames[1:], strict=False)):
        raise ValueError(f"{what} must have strictly increasing frames, got {frames}")
    return keys


class FrameState(BaseModel):
    """What one frame shows: the camera (None: as loaded), each moving shape's
    (translate, angle) and each changed emitter's radiance scale."""

    model_config = ConfigDict(frozen=True)

    camera: tuple[Vector3, Vector3, Vector3, float | None] | None
    shapes: dict[str, tuple[Vector3, float]]
    emitters: dict[str, float]


class Animation(_Strict):
    """A scene's animation (module docstring); validated on construction."""

    camera: list[CameraKey] = Field(default_factory=list, max_length=MAX_ITEMS)
    shapes: list[ShapeMotion] = Field(default_factory=list, max_length=MAX_ITEMS)
    emitters: list[EmitterChange] = Field(default_factory=list, max_length=MAX_ITEMS)
    disocclusions: list[int] = Field(
        default_factory=list, max_length=MAX_ITEMS,
        description="frames (>= 1) at which every pixel's motion vector is invalid")

    @field_validator("camera")
    @classmethod
    def _camera_ordered(cls, keys: list[CameraKey]) -> list[CameraKey]:
        if keys and len({key.fov is None for key in keys}) > 1:
            raise ValueError("camera keys must all give fov or none of them")
        return _increasing(keys, "camera keys")

    @field_validator("disocclusions")
    @classmethod
    def _disocclusions(cls, frames: list[int]) -> list[int]:
        if any(not 1 <= frame <= MAX_FRAME for frame in frames):
            raise ValueError(f"disocclusion frames must be 1..{MAX_FRAME}, got {frames}")
        if any(b <= a for a, b in zip(frames, frames[1:], strict=False)):
            raise ValueError(f"disocclusion frames must increase strictly, got {frames}")
        return frames

    @model_validator(mode="after")
    def _consistent(self) -> Animation:
        if not (self.camera or self.shapes or self.emitters or self.disocclusions):
            raise ValueError("an animation needs camera keys, shape motions or emitter "
                             "changes (or disocclusions)")
        names = [motion.shape for motion in self.shapes]
        if len(set(names)) != len(names):
            raise ValueError(f"a shape has two motions: {sorted(names)}")
        changes = sorted((c.emitter, c.frame) for c in self.emitters)
        if len(set(changes)) != len(changes):
            raise ValueError("an emitter changes twice at the same frame")
        return self

    def digest(self) -> str:
        # Animations without disocclusions keep the digests they had before they existed.
        return digest("animation", self.model_dump(
            mode="json", exclude=None if self.disocclusions else {"disocclusions"}))

    def disocclusions_until(self, frame: int) -> int:
        """How many disocclusions happened up to ``frame`` (inclusive)."""
        return sum(1 for disocclusion in self.disocclusions if disocclusion <= frame)

    def state(self, frame: int) -> FrameState:
        camera = None
        if self.camera:
            flat = _sample(self.camera, frame, _camera_values)
            camera = (flat[0:3], flat[3:6], flat[6:9],
                      None if self.camera[0].fov is None else flat[9])
        shapes = {motion.shape: _split_motion(_sample(motion.keys, frame, _motion_values))
                  for motion in self.shapes}
        emitters: dict[str, float] = {}
        for change in sorted(self.emitters, key=lambda c: c.frame):
            if change.frame <= frame:
                emitters[change.emitter] = change.scale
            else:
                emitters.setdefault(change.emitter, 1.0)
        return FrameState(camera=camera, shapes=shapes, emitters=emitters)

    def state_key(self, frame: int) -> str:
        """Names frame ``frame``'s state: frames with equal keys show the same image."""
        rounded = json_rounded(self.state(frame).model_dump(mode="json"))
        return digest("animation-state", rounded)

    def change_frames(self) -> list[int]:
        """The frames at which the state jumps (emitter changes, step keys; not frame 0)
        and the disocclusions."""
        steps = [key.frame for key in self.camera if key.step] + self.disocclusions
        steps += [key.frame for motion in self.shapes for key in motion.keys if key.step]
        steps += [change.frame for change in self.emitters]
        return sorted({frame for frame in steps if frame > 0})

    def change_labels(self) -> list[str]:
        """What happens at each change frame (in :meth:`change_frames`' order), in a few
        words: e.g. '8 lights off', 'light x4', 'door moves', 'camera cut'."""
        return [self._change_label(frame) for frame in self.change_frames()]

    def _change_label(self, frame: int) -> str:
        before, after = self.state(frame - 1).emitters, self.state(frame).emitters
        kinds: dict[str, int] = {}
        for change in self.emitters:
            if change.frame == frame and after[change.emitter] != before[change.emitter]:
                kind = ("off" if change.scale == 0 else "on" if before[change.emitter] == 0
                        else f"x{change.scale:g}")
                kinds[kind] = kinds.get(kind, 0) + 1
        parts = [f"{count} lights {kind}" if count > 1 else f"light {kind}"
                 for kind, count in kinds.items()]
        parts += [f"{motion.shape} moves" for motion in self.shapes
                  if any(key.step and key.frame == frame for key in motion.keys)]
        parts += ["camera cut" for key in self.camera if key.step and key.frame == frame]
        parts += ["disocclusion" for disocclusion in self.disocclusions if disocclusion == frame]
        return ", ".join(parts) or f"change at frame {frame}"


def json_rounded(value: Any) -> Any:
    if isinstance(value, float):
        return round(value, KEY_DECIMALS) + 0.0
    if isinstance(value, dict):
        return {key: json_rounded(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [json_rounded(item) for item in value]
    return value


def _camera_values(key: CameraKey) -> tuple[float, ...]:
    """A camera key as one vector (position, target, up, fov; the fov 0 where none is
    given: then no key gives one), interpolated as a whole."""
    return (*key.position, *key.target, *key.up, key.fov or 0.0)


def _motion_values(key: ShapeKey) -> tuple[float, ...]:
    return (*key.translate, key.angle_deg)


def _split_motion(values: tuple[float, ...]) -> tuple[Vector3, float]:
    return (values[0], values[1], values[2]), values[3]


def _sample(keys: list[Any], frame: int, value: Any) -> tuple[float, ...]:
    """``value`` of the keys at ``frame``: linear between keys, held before the first,
    after the last and before a step key."""
    if frame <= keys[0].frame:
        return tuple(value(keys[0]))
    for before, after in zip(keys, keys[1:], strict=False):
        if frame < after.frame:
            if after.step:
                return tuple(value(before))
            weight = (frame - before.frame) / (after.frame - before.frame)
            return tuple((1 - weight) * a + weight * b
                         for a, b in zip(value(before), value(after), strict=True))
    return tuple(value(keys[-1]))


def rigid_matrix(translate: Vector3, angle_deg: float, axis: Vector3,
                 pivot: Vector3) -> np.ndarray:
    """4x4 T(translate) * T(pivot) * R(axis, angle) * T(-pivot) (Rodrigues' formula)."""
    unit = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    angle = math.radians(angle_deg)
    cross = np.array([[0, -unit[2], unit[1]], [unit[2], 0, -unit[0]], [-unit[1], unit[0], 0]])
    rotation = np.eye(3) + math.sin(angle) * cross + (1 - math.cos(angle)) * cross @ cross
    matrix = np.eye(4)
    matrix[:3, :3] = rotation
    pivot_np = np.asarray(pivot, dtype=np.float64)
    matrix[:3, 3] = pivot_np - rotation @ pivot_np + np.asarray(translate, dtype=np.float64)
    return matrix


def look_at_matrix(position: Vector3, target: Vector3, up: Vector3) -> np.ndarray:
    """Mitsuba's look-at camera-to-world matrix (the camera looks down its +z)."""
    origin = np.asarray(position, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - origin
    forward /= np.linalg.norm(forward)
    left = np.cross(np.asarray(up, dtype=np.float64), forward)
    left /= np.linalg.norm(left)
    new_up = np.cross(forward, left)
    matrix = np.eye(4)
    matrix[:3, 0], matrix[:3, 1], matrix[:3, 2], matrix[:3, 3] = left, new_up, forward, origin
    return matrix


class AnimationPlayer:
    """Applies an animation's frames to one ``mi.Scene`` (module docstring). Every name
    the animation uses is checked against the scene on construction (SceneError)."""

    def __init__(self, scene: Any, animation: Animation) -> None:
        import mitsuba as mi

        self.animation = animation
        self.params = mi.traverse(scene)
        self.update_seconds: list[float] = []   # of the applies that changed the scene
        self.scene = scene
        self._current: tuple[str, int] | None = None
        self._rest: dict[str, Any] = {}
        self._moved: dict[str, np.ndarray] = {}   # the last matrix applied to each shape
        self._camera_state: Any = None   # the last camera applied (FrameState.camera)
        if animation.camera:
            sensor = scene.sensors()[0].id()
            self._camera = (f"{sensor}.to_world", f"{sensor}.x_fov")
            self._keep(self._camera[0], "camera")
            if animation.camera[0].fov is not None:
                self._keep(self._camera[1], "camera")
        self._shapes = {motion.shape: self._shape_key(motion.shape) for motion in animation.shapes}
        self._emitters = {change.emitter: self._emitter_key(change.emitter)
                          for change in animation.emitters}

    def _keep(self, key: str, what: str) -> None:
        if key not in self.params:
            raise SceneError(f"animation: the scene has no {what} parameter '{key}'")
        value = self.params[key]
        self._rest[key] = (np.array(value.matrix, dtype=np.float64)[..., 0]
                           if hasattr(value, "matrix") else np.array(value, dtype=np.float64))

    def _shape_key(self, name: str) -> str:
        for key in (f"{name}.to_world", f"{name}.vertex_positions"):
            if key in self.params:
                self._keep(key, "shape")
                return key
        movable = sorted({key.rsplit(".", 1)[0] for key in self.params.keys()
                          if key.endswith((".to_world", ".vertex_positions"))
                          and "." not in key.rsplit(".", 1)[0]} - {self._sensor_id()})
        raise SceneError(f"animation: no shape '{name}' to move; the scene's shapes: "
                         f"{', '.join(movable)}")

    def _emitter_key(self, name: str) -> str:
        for key in (f"{name}.emitter.radiance.value", f"{name}.radiance.value"):
            if key in self.params:
                value = self.params[key]
                self._rest[key] = type(value)(value)   # a copy: scaled on every change
                return key
        emitters = sorted(key.split(".", 1)[0] for key in self.params.keys()
                          if key.endswith("radiance.value"))
        raise SceneError(f"animation: no emitter '{name}' with a radiance to change; the "
                         f"scene's: {', '.join(emitters)}")

    def _sensor_id(self) -> str:
        return self._camera[0].split(".", 1)[0] if self.animation.camera else ""

    def apply(self, frame: int) -> None:
        """Show frame ``frame``: set the changed parameters and update the scene, timed
        into :attr:`update_seconds` (nothing happens where the state is unchanged)."""
        import drjit as dr
        import mitsuba as mi

        from renderers.frozen import camera_changed, geometry_changed, lights_changed

        # A disocclusion changes no parameter, but is a scene update of its own.
        state_key = (self.animation.state_key(frame), self.animation.disocclusions_until(frame))
        if state_key == self._current:
            return
        start = time.perf_counter()
        state = self.animation.state(frame)
        camera_moved = state.camera != self._camera_state
        if state.camera is not None:
            position, target, up, fov = state.camera
            self.params[self._camera[0]] = mi.AffineTransform4f(
                look_at_matrix(position, target, up))
            if fov is not None:
                self.params[self._camera[1]] = fov
        meshes_moved = False
        for motion in self.animation.shapes:
            translate, angle = state.shapes[motion.shape]
            key = self._shapes[motion.shape]
            matrix = rigid_matrix(translate, angle, motion.axis, motion.pivot)
            if not np.array_equal(matrix, self._moved.get(key)):
                self._move(key, matrix)
                meshes_moved |= key.endswith(".vertex_positions")
        for name, scale in state.emitters.items():
            radiance = self._emitters[name]
            self.params[radiance] = self._rest[radiance] * scale
        self.params.update()
        if meshes_moved:
            geometry_changed(self.scene)
        if camera_moved:   # what was derived from the camera is derived again
            camera_changed(self.scene)
            self._camera_state = state.camera
        # Light selection tables (emitter powers, positions) follow shapes and emitters;
        # a state named anew after each disocclusion makes ReSTIR drop its history
        # (renderers.integrators.restir).
        lights = json_rounded(state.model_dump(mode="json", include={"shapes", "emitters"}))
        disocclusions = state_key[1]
        lights_changed(self.scene, digest("animation-lights", lights, disocclusions)
                       if disocclusions else digest("animation-lights", lights))
        dr.sync_thread()
        self.update_seconds.append(time.perf_counter() - start)
        self._current = state_key

    def _move(self, key: str, matrix: np.ndarray) -> None:
        import mitsuba as mi

        self._moved[key] = matrix
        rest = self._rest[key]
        if key.endswith(".to_world"):
            self.params[key] = mi.AffineTransform4f(matrix @ rest)
            return
        points = rest.reshape(-1, 3)
        moved = points @ matrix[:3, :3].T + matrix[:3, 3]
        self.params[key] = mi.Float(moved.ravel().astype(np.float32))
