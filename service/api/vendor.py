"""The chart library the dashboard runs, and the OpenAPI page's viewer, served by the
app itself (no CDN).

One JavaScript file holds Vega, Vega-Lite and vega-embed, as the installed
vl-convert-python package bundles them (``vl_convert.javascript_bundle``): the page
and the files rendered with vl-convert draw the same specs with the same libraries.
The bundle is made once per process (a few seconds), started in the background when
the app starts, and kept in memory.

ReDoc (``/redoc``) runs the fastapi-offline package's copy of its standalone script
with every image it would fetch from another host (its footer's Redocly logo) taken
out (:func:`redoc_script`): the page makes no request outside this service.
"""

from __future__ import annotations

import re
import threading
from functools import cache
from pathlib import Path

import fastapi_offline
import vl_convert
from fastapi import APIRouter, Response

router = APIRouter(include_in_schema=False)

VEGA_PATH = "/vendor/vega.js"
REDOC_PATH = "/vendor/redoc.js"
#: An image the viewer would load from another host: ``src:"https://..."``.
REMOTE_IMAGE = re.compile(rb'src:"(?:https?:)?//[^"]*"')
_lock = threading.Lock()
_bundle: bytes | None = None


def vega_bundle() -> bytes:
    """The bundle, made on the first call (the others wait for it)."""
    global _bundle
    with _lock:
        if _bundle is None:
            _bundle = vl_convert.javascript_bundle().encode()
        return _bundle


def warm_up() -> None:
    """Start making the bundle in the background, so the first page need not wait."""
    threading.Thread(target=vega_bundle, name="vega-bundle", daemon=True).start()


@router.get(VEGA_PATH)
def vega_script() -> Response:
    return Response(vega_bundle(), media_type="text/javascript",
                    headers={"Cache-Control": "public, max-age=86400",
                             "X-Bundle-Version": vl_convert.__version__})


@cache
def redoc_script() -> bytes:
    """ReDoc's standalone script without images from another host (module docstring);
    their components hide themselves when the image does not load."""
    bundle = Path(fastapi_offline.__file__).parent / "static" / "redoc.standalone.js"
    return REMOTE_IMAGE.sub(b'src:""', bundle.read_bytes())


@router.get(REDOC_PATH)
def redoc() -> Response:
    return Response(redoc_script(), media_type="text/javascript",
                    headers={"Cache-Control": "public, max-age=86400"})
