"""Image files: float32 EXR through the OpenEXR 3.x Python API, PNG through pillow.

- :func:`read_exr` returns float32 (H, W, 3) for RGB(A) files (alpha dropped)
  and (H, W, 1) for luminance-only (``Y``) files; ``layer="variance"`` reads
  ``variance.R/G/B`` instead. Anything unreadable raises :class:`ImageReadError`
  with a one-line message naming the file.
- :func:`write_exr` writes float32, ZIP-compressed (lossless: values round-trip
  bit for bit, NaN and Inf included) scanline EXR; :func:`write_png` writes
  8-bit PNG.

Writes are atomic: the file is written under a temporary name in the same
directory, flushed to disk, then renamed over the target with ``os.replace``,
so readers (and a crash) never see a half-written image. Writes are checked: the
file is read back (an EXR's header: its size and channels; a PNG decoded) before it
is renamed into place, because an encoder can report success for a file that a full
disk left empty; a failed write or check raises :class:`ImageWriteError`, an
``OSError`` (errno ``EIO``, or the encoder's own), never a silent empty image.

Note: on a damaged EXR the OpenEXR binding prints a one-line warning to stdout
before we raise ImageReadError; it cannot be silenced without redirecting the
process's stdout.
"""

from __future__ import annotations

import errno
import io
import os
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image

PathLike = str | os.PathLike[str]

#: Default channel names by channel count.
_DEFAULT_CHANNELS = {1: ("Y",), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}


class ImageReadError(ValueError):
    """An image file is missing, damaged, or lacks the channels asked for."""


class ImageWriteError(OSError):
    """An image could not be written whole (a full disk, a file size limit, an I/O
    error); ``errno`` is the cause's when known, else ``EIO``."""

    def __init__(self, path: Path, cause: str, code: int = errno.EIO) -> None:
        super().__init__(code, f"could not write the image {path.name}: {cause}", str(path))


# ---- Atomic writes ----------------------------------------------------------


@contextmanager
def _atomic_target(path: PathLike, check: Callable[[Path], None]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; once written, fsync it, ``check`` it
    (raises on a file that does not read back as written) and rename it over ``path``."""
    target = Path(path)
    # A fresh name (not mkstemp) so the writer creates the file with the
    # process umask rather than mkstemp's 0600.
    tmp = target.with_name(f".{target.name}.{uuid.uuid4().hex}.tmp")
    try:
        yield tmp
        with open(tmp, "rb") as handle:
            os.fsync(handle.fileno())
        check(tmp)
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


# ---- EXR --------------------------------------------------------------------


def _channel_names(channels: Sequence[str] | None, count: int) -> tuple[str, ...]:
    if channels is None:
        if count not in _DEFAULT_CHANNELS:
            raise ValueError(f"cannot name {count} channels by default; pass channels=[...]")
        return _DEFAULT_CHANNELS[count]
    names = tuple(channels)
    if len(names) != count or len(set(names)) != count:
        raise ValueError(f"need {count} distinct channel names for an image with {count} "
                         f"channels, got {names}")
    return names


def write_exr(path: PathLike, img: np.ndarray, channels: Sequence[str] | None = None) -> None:
    """Write ``img`` as a float32 EXR, atomically.

    ``img`` is (H, W) or (H, W, C). Channel names default to Y / RGB / RGBA by
    channel count; pass ``channels`` to name them, e.g.
    ``["variance.R", "variance.G", "variance.B"]`` for a named layer.
    """
    arr = np.asarray(img)
    if arr.ndim == 2:
        arr = arr[..., np.newaxis]
    if arr.ndim != 3 or 0 in arr.shape:
        raise ValueError(f"EXR images must be (H, W) or (H, W, C), got shape {arr.shape}")
    names = _channel_names(channels, arr.shape[2])
    pixels = {name: np.ascontiguousarray(arr[..., i], dtype=np.float32)
              for i, name in enumerate(names)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}

    def check(tmp: Path) -> None:
        try:
            written = OpenEXR.File(str(tmp), header_only=True)
            window = written.header()["dataWindow"]
            shape = (int(window[1][1] - window[0][1] + 1), int(window[1][0] - window[0][0] + 1))
            found = {channel.name for channel in written.header()["channels"]}
        except (RuntimeError, ValueError, OSError, KeyError, IndexError) as err:
            raise ImageWriteError(Path(path), f"it does not read back ({err})") from None
        if shape != arr.shape[:2] or found != set(names):
            raise ImageWriteError(Path(path), f"it reads back as {shape} with {sorted(found)}")

    with _atomic_target(path, check) as tmp:
        try:
            OpenEXR.File(header, pixels).write(str(tmp))
        except RuntimeError as err:   # OpenEXR reports a failed write this way, errno lost
            raise ImageWriteError(Path(path), str(err)) from None


def _open_exr(path: Path) -> OpenEXR.File:
    if not path.is_file():
        raise ImageReadError(f"cannot read {path}: no such file")
    if not OpenEXR.isOpenExrFile(str(path)):
        raise ImageReadError(f"cannot read {path}: not an OpenEXR file")
    try:
        exr = OpenEXR.File(str(path), separate_channels=True)
    except (RuntimeError, ValueError, OSError) as err:
        raise ImageReadError(f"cannot read {path}: damaged EXR file ({err})") from None
    # A truncated file opens without an exception but with no readable part.
    if not exr.parts:
        raise ImageReadError(f"cannot read {path}: damaged or truncated EXR file")
    return exr


def read_exr(path: PathLike, layer: str | None = None) -> np.ndarray:
    """float32 (H, W, 3) RGB, or (H, W, 1) for a Y-only file, from the first part of an EXR.

    ``layer`` selects channels named ``<layer>.R`` etc. Raises ImageReadError
    for a missing, non-EXR, damaged or truncated file, or one without R, G, B
    or Y channels.
    """
    path = Path(path)
    channels = _open_exr(path).channels()
    prefix = f"{layer}." if layer else ""
    for names in (("R", "G", "B"), ("Y",)):
        if all(prefix + name in channels for name in names):
            planes = [np.asarray(channels[prefix + name].pixels) for name in names]
            if any(p.ndim != 2 or p.shape != planes[0].shape for p in planes):
                raise ImageReadError(f"cannot read {path}: subsampled or mismatched channels")
            return np.stack(planes, axis=-1).astype(np.float32)
    found = ", ".join(sorted(channels)) or "none"
    raise ImageReadError(f"cannot read {path}: no {prefix}R/G/B or {prefix}Y channels "
                         f"(found: {found})")


# ---- PNG --------------------------------------------------------------------


def _png_image(rgb_uint8: np.ndarray) -> Image.Image:
    arr = np.asarray(rgb_uint8)
    if arr.dtype != np.uint8:
        raise ValueError(f"PNG previews must be uint8, got {arr.dtype}")
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] in (3, 4))):
        raise ValueError(f"PNG images must be (H, W), (H, W, 3) or (H, W, 4), got {arr.shape}")
    return Image.fromarray(np.ascontiguousarray(arr))


def write_png(path: PathLike, rgb_uint8: np.ndarray) -> None:
    """Write an 8-bit (H, W, 3) RGB (or (H, W) grey, (H, W, 4) RGBA) image as PNG, atomically."""
    image = _png_image(rgb_uint8)

    def check(tmp: Path) -> None:
        try:
            with Image.open(tmp) as written:
                written.load()
                size = written.size
        except (OSError, ValueError, SyntaxError) as err:
            raise ImageWriteError(Path(path), f"it does not read back ({err})") from None
        if size != image.size:
            raise ImageWriteError(Path(path), f"it reads back as {size}")

    with _atomic_target(path, check) as tmp:
        image.save(tmp, format="PNG")


def png_bytes(rgb_uint8: np.ndarray) -> bytes:
    """The PNG encoding of an 8-bit image (as for ``write_png``), in memory."""
    buffer = io.BytesIO()
    _png_image(rgb_uint8).save(buffer, format="PNG")
    return buffer.getvalue()
