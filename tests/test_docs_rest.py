"""Every request body docs/rest.md submits to POST /api/v1/jobs or /api/v1/sweeps is a
valid spec, as the service reads it (a CLI user's parameter sweep over REST is
'parameter', not the CLI's '--sweep')."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from pydantic import ValidationError

from jobs.protocol.spec import RenderSpec, SweepSpec

REST = Path(__file__).resolve().parents[1] / "docs" / "rest.md"
#: A curl POST to the jobs or sweeps endpoint and its literal JSON body ('-d '{...}'').
POST = re.compile(r'"\$NB/api/v1/(jobs|sweeps)" [^\n]*\\\n\s*-d \'(\{.*?\})\'', re.DOTALL)
SPECS = {"jobs": RenderSpec, "sweeps": SweepSpec}


def bodies(text: str) -> list[tuple[str, dict]]:
    return [(endpoint, json.loads(body)) for endpoint, body in POST.findall(text)]


def test_every_documented_job_and_sweep_body_is_a_valid_spec():
    found = bodies(REST.read_text())
    assert {endpoint for endpoint, _ in found} == {"jobs", "sweeps"}
    assert any("parameter" in body for _, body in found)       # the parameter sweep
    for endpoint, body in found:
        SPECS[endpoint].model_validate(body)
    # Planted: the CLI's option name as a body field is refused.
    planted = '"$NB/api/v1/sweeps" -H x \\\n  -d \'{"scene": "door", "sweep": "sph_c=0.01,0.1"}\''
    ((endpoint, body),) = bodies(planted)
    with pytest.raises(ValidationError, match="sweep"):
        SPECS[endpoint].model_validate(body)
