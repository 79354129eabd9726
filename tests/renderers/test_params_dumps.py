"""A method's parameters dump, store and hash as they did before the termination
policy's parameters were held as a typed object.

``golden/params_before.json`` holds, for every method, its defaults, every policy it
accepts with and without parameters of the policy's own, cache overrides, and the
parameter sets of the CI suite and its baseline, each with the dump
(``model_dump(mode="json")``) the code before made of it. The keys of runs, references,
sweeps and idempotency hash these dumps as canonical JSON (sorted keys).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, get_args

import pytest

from renderers.methods import METHODS, parse_params
from renderers.seeding import canonical_json

BEFORE = json.loads((Path(__file__).parent / "golden" / "params_before.json").read_text())


def _dump(method: str, params: dict[str, Any]) -> dict[str, Any]:
    return parse_params(method, params).model_dump(mode="json")


#: Parameters a method gained since the golden dumps were made, with the estimator version
#: that brought them (its runs are keyed anew anyway) and their defaults: a parameter set
#: dumps as before with these taken out, and they dump their defaults when not given.
ADDED_SINCE: dict[str, tuple[int, dict[str, Any]]] = {
    "grid-cache": (2, {"prefill_history": 2, "prefill_tolerance": 0.002}),
}
#: Defaults changed since, with the estimator version that changed them: (before, now).
CHANGED_SINCE: dict[str, tuple[int, dict[str, tuple[Any, Any]]]] = {
    "grid-cache": (3, {"prefill_frames": (48, 128)}),
}


@pytest.mark.parametrize("entry", BEFORE, ids=lambda e: f"{e['method']} {canonical_json(e['params'])}")
def test_a_parsed_parameter_set_dumps_as_before(entry):
    dumped = _dump(entry["method"], entry["params"])
    version, added = ADDED_SINCE.get(entry["method"], (None, {}))
    if added:
        assert METHODS[entry["method"]].version >= version
        assert {name: dumped.pop(name) for name in added} == added
    version, changed = CHANGED_SINCE.get(entry["method"], (None, {}))
    for name, (before, now) in changed.items():
        assert METHODS[entry["method"]].version >= version
        if name not in entry["params"]:
            assert dumped[name] == now
            dumped[name] = before
    assert canonical_json(dumped) == canonical_json(entry["dump"])
    assert list(dumped) == list(entry["dump"])          # the same fields, in the same order


def test_the_comparison_sees_a_policy_parameter_dumped_that_was_not_given():
    """Dumping every parameter of the policy, given or not, would change the keys of
    every run that set some of them."""
    def planted(entry: dict[str, Any]) -> dict[str, Any]:
        params = parse_params(entry["method"], entry["params"])
        dumped = params.model_dump(mode="json")
        if "termination_params" in dumped:
            dumped["termination_params"] = params.termination_params.model_dump(
                mode="json", exclude={"policy"})
        return dumped

    assert any(canonical_json(planted(e)) != canonical_json(e["dump"]) for e in BEFORE)


def _policies(method: str) -> tuple[str, ...]:
    return get_args(METHODS[method].params.model_fields["termination"].annotation)


@pytest.mark.parametrize("method", [m for m in METHODS
                                    if "termination" in METHODS[m].params.model_fields])
def test_every_policy_of_every_method_round_trips(method):
    """Each registered policy a method accepts: named alone it dumps as its name, and
    with its own parameters set to their defaults explicitly they are kept as given;
    either dump parses back to itself."""
    for policy in _policies(method):
        alone = _dump(method, {"termination": policy})
        assert alone["termination"] == policy and "termination_params" not in alone
        params = parse_params(method, {"termination": policy})
        own = params.termination_params.model_dump(mode="json", exclude={"policy"})
        given = _dump(method, {"termination": policy, "termination_params": own})
        assert given.get("termination_params", {}) == own
        for dumped in (alone, given):
            assert canonical_json(_dump(method, dumped)) == canonical_json(dumped)
