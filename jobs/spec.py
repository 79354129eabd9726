"""Job specifications: what a render job is, validated before anything runs.

A spec is plain data (pydantic): the CLI builds one from its options, the REST
API from a request body; the executor runs it. Out-of-range values are
rejected here with a message naming the field.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from renderers.methods.pt import DEFAULT_MAX_DEPTH
from renderers.reference import ReferenceSettings
from renderers.seeding import digest


class ReferenceSpec(BaseModel):
    """How the converged reference of a job is rendered (see renderers.reference)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    integrator: Literal["path", "pt"] = "path"
    spp: int = Field(4096, ge=8, le=1 << 24)
    spp_per_pass: int = Field(64, ge=1, le=1 << 16)
    rel_stderr: float | None = Field(None, gt=0.0, le=1.0)

    def settings(self, max_depth: int) -> ReferenceSettings:
        return ReferenceSettings(integrator=self.integrator, max_depth=max_depth, spp=self.spp,
                                 spp_per_pass=self.spp_per_pass, rel_stderr=self.rel_stderr)


class RenderSpec(BaseModel):
    """One render job: a method on a scene, K seeds, compared with a reference."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    scene: str = Field(min_length=1, description="built-in scene name or path to a Mitsuba XML")
    method: str = "pt"
    params: dict[str, Any] = Field(default_factory=dict)
    resolution: int = Field(64, ge=1, le=8192, description="image width and height in pixels")
    spp: int = Field(1, ge=1, le=1 << 16, description="samples per pixel per frame")
    frames: int = Field(1, ge=1, le=100_000)
    seeds: int = Field(4, ge=1, le=1000, description="K independent renders (rBias2/rVar need 2+)")
    eps: float = Field(0.01, gt=0.0, le=1.0, description="relative-error epsilon of MRSE")
    reference: ReferenceSpec = Field(default_factory=ReferenceSpec)
    keep_frames: bool = False

    def max_depth(self) -> int:
        """The method's path depth, which its reference must share."""
        return int(self.params.get("max_depth", DEFAULT_MAX_DEPTH))

    def key(self) -> str:
        """Content address of the spec (equal specs give equal keys)."""
        return digest("render-spec", self.model_dump(mode="json"))
