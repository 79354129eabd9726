"""A render job is parsed once, where it enters, into one typed immutable object.

The keys that address stored work (render and sweep specs, the queue's
idempotency keys, references, the method parameters that go into sweep-point and
snapshot keys) are those computed by the code before jobs were parsed once: the
values below were computed with it, so stored results stay comparable. A
method's estimator version is part of its render keys, so a bump gives new ones:
the restir values are those of `restir-di` version 4 (temporal reuse along motion
vectors). The metric
version is part of every key but the parameters' (references included): GOLDEN holds
those of metric version 3 (a cache method's rBias² the mean over its caches), and at
version 2 the code still gives the values from before.

The N_c sweep's spec keys are the exception: since it became a parameter sweep over
NIRC's ``nc`` (NIRC alone, the termination policy one of its parameters) its spec dumps
otherwise, and the store migration 0011 re-keys the stored ones (its test). Its points
keep their keys (``N_C_POINT_KEYS``, computed by the code before).
"""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path
from types import SimpleNamespace

import pytest

from jobs.execution.queue import spec_key
from jobs.protocol.job import RenderJob
from jobs.protocol.references import reference_key
from jobs.protocol.spec import RenderSpec, SweepSpec, TimeBudget
from renderers.methods import MethodError, parse_params
from renderers.seeding import digest

ROOT = Path(__file__).resolve().parents[2]

RENDERS = {
    "pt": RenderSpec(scene="cornell-box"),
    "nirc_adaptive": RenderSpec(scene="cornell-box", method="nirc",
                                params={"termination": "adaptive", "nc": [8, 1]}, seeds=2),
    "nrc_budget": RenderSpec(scene="door", method="nrc",
                             params={"termination": "sph", "sph_c": 0.02},
                             time_budget=TimeBudget(ms=5.0)),
    "restir": RenderSpec(scene="many-lights", method="restir-di", seed_start=4),
}
SWEEPS = {
    "eps": SweepSpec(scene="cornell-box", eps=[0.1, 0.3]),
    "nc": SweepSpec(scene="cornell-box", nc=[1, 2], termination="sph", params={"sph_c": 0.02}),
}
PARAMS = [("nirc", t) for t in ("bth", "sph", "adaptive")] + [("nrc", t) for t in ("sph", "adaptive")]

GOLDEN_METRIC_VERSION_2 = {
    "render-spec pt":
        "b4f2cab8e2bcd3add62ff1df8a878fd9a821b06a669cda02283b1a58241ea506",
    "idempotency render pt":
        "b5678091e73286e49cb0b29782b458f34205dbfa77a4f182d702c8d9188550ed",
    "reference pt":
        "3052614eb2624108d207454ec5c419a5",
    "render-spec nirc_adaptive":
        "7dc660aead47fc5e18c2c92746a971c7ce8bf910e16fda22018712df34fbeabb",
    "idempotency render nirc_adaptive":
        "dd3ad1d30c66e0c0a04b2def1b7e86e741126c01512fe5e6363bb84968979794",
    "reference nirc_adaptive":
        "3052614eb2624108d207454ec5c419a5",
    "render-spec nrc_budget":
        "7b9613b6feaf15c8a5ac4c304116b1e93c882a833c728c00849a22f6864de9bf",
    "idempotency render nrc_budget":
        "852e8d564ed844070317d6d1b117ba425e03a82b2ee0b476087205372f62e41c",
    "reference nrc_budget":
        "3052614eb2624108d207454ec5c419a5",
    "render-spec restir":
        "2d741ba0c5990a5857005ea3881a7c4030de7ccebfaf7a187e030e138bf22546",
    "idempotency render restir":
        "020b7e47c0f2060d5b8afb71eb4e042c025d72e57ac57cce328afa85e055171b",
    "reference restir":
        "614aaaa5d49d8d801ac6691d429eb33b",
    "sweep-spec eps":
        "665e289d1f4e2fe6acfc7f5aabc90b426fe64d4535bdb7a0291740aea6cba105",
    "idempotency sweep eps":
        "a9d3b106cc60381207a6797a771313c0786db9873bf2ad3bec71b3adc861922e",
    "sweep-spec nc":
        "94f48b70f21bafe3d0bdaca75fd48baebb84041ce7666e11b56e013d602c0d63",
    "idempotency sweep nc":
        "e595ee4fde2e399c80f3a4f450bf8d1338ca6395634fd264cb22fd5b95bcc899",
    "params nirc bth":
        "39c614cd6df7d3c6db1c1da2de621cce85540fb8458c96b2d2fe29b5109a8e2a",
    "params nirc sph":
        "14b7d8ae15c57b49021f441a637232be6673f79ae409bd49d8c81e63afeed603",
    "params nirc adaptive":
        "f1346ac316a6feeb020a264181d4cc6fa29ce3c40a344bee4d46bfb1ee1c46cb",
    "params nrc sph":
        "17b639b1740769bd442eb745eb4019c3a9a26e6d5027fd3b1f0b01dac511663d",
    "params nrc adaptive":
        "7dc19c287c5f488eacbee4fe60e80844589bb8e8383e0b81621c1d8d703049ae",
}

# Metric version 3: every key but the method parameters' moved with it.
GOLDEN = GOLDEN_METRIC_VERSION_2 | {
    "render-spec pt":
        "7be3b3012668ca3d5538b187f86cdf3416c4e90f3fa540bbed57434fb0995151",
    "idempotency render pt":
        "df34c4d9566473d79c78561c8bf226e18c639bc311d42f150dcb2c98cc6a5ca0",
    "reference pt":
        "8a051e1238ea066ca5ae9b46f38c38fd",
    "render-spec nirc_adaptive":
        "c075162b18bf210be68d8d64137381435229f61506f8e8c7e52a9234087e2b35",
    "idempotency render nirc_adaptive":
        "ce5e70b01c38bb0a145db345012f0bcdc5fbf544504248624f9472824f0d08a1",
    "reference nirc_adaptive":
        "8a051e1238ea066ca5ae9b46f38c38fd",
    "render-spec nrc_budget":
        "ae74e88fe3d1f86b378dc16bde5f7d70b4157bc40e2b2c844f0d9d3293c11bc0",
    "idempotency render nrc_budget":
        "2bd80b149b22739be8d862bc52efc8b4ec5620876951ea14c6121eb66be2d4d9",
    "reference nrc_budget":
        "8a051e1238ea066ca5ae9b46f38c38fd",
    "render-spec restir":
        "ca1999f96ac7818015bd8b4d0430e8f865811aeaec17691082e93fbb35967e0b",
    "idempotency render restir":
        "4a3cf138d2e8b228a6cdcb374e8b5635546eb63143c77edb5b26fb20d5080063",
    "reference restir":
        "e43fd70126694313b3d2c3e797dc254d",
    "sweep-spec eps":
        "5346ccc38e511a30af495cde43dca3bb01cb68428430eeb3fc22838e5c6b92a1",
    "idempotency sweep eps":
        "4751e7efbade1f4c2806a4d48a0cc60e34e7b45c5a4c1c57367267ab85a0c37c",
    "sweep-spec nc":
        "49e45331bc0e76cbab9194348376f4e5ed333d3b399b6048293036da0e713416",
    "idempotency sweep nc":
        "bb6940fa7a59ad2925ae89828a6d89323057660fc80705a63ed64367d77b3dbb",
}


def _keys() -> dict[str, str]:
    scene = SimpleNamespace(fingerprint="fingerprint", resolution=(64, 64))
    out = {}
    for name, spec in RENDERS.items():
        out[f"render-spec {name}"] = spec.key()
        out[f"idempotency render {name}"] = spec_key("render", spec, "cpu")
        out[f"reference {name}"] = reference_key(
            scene, spec.reference.settings(RenderJob.parse(spec).max_depth))
    for name, sweep in SWEEPS.items():
        out[f"sweep-spec {name}"] = sweep.key("device")
        out[f"idempotency sweep {name}"] = spec_key("sweep", sweep, "cpu")
    for method, termination in PARAMS:
        dumped = parse_params(method, {"termination": termination}).model_dump(mode="json")
        out[f"params {method} {termination}"] = digest(dumped)
    return out


def test_stored_keys_are_those_from_before():
    assert _keys() == GOLDEN


def test_denoising_keys_a_spec_anew_only_where_it_is_on():
    """The ``denoised`` option is dumped, stored and keyed only where it is on, so the
    keys above (all with it off) stay; on, it keys a different job."""
    off = RENDERS["pt"]
    on = RenderSpec(scene="cornell-box", denoised=True)
    assert "denoised" not in off.model_dump(mode="json")
    assert RenderSpec.model_validate(on.model_dump(mode="json")) == on
    assert on.key() != off.key()
    assert spec_key("render", on, "cpu") != spec_key("render", off, "cpu")


def test_a_job_is_immutable():
    job = RenderJob.parse(RENDERS["nirc_adaptive"])
    with pytest.raises(dataclasses.FrozenInstanceError):
        job.params = None  # type: ignore[misc]
    with pytest.raises(Exception, match="frozen"):
        job.params.nc = [1]  # type: ignore[misc]
    with pytest.raises(Exception, match="frozen"):
        job.spec.spp = 2  # type: ignore[misc]


def test_a_job_parses_its_spec_and_knows_its_depth():
    job = RenderJob.parse(RENDERS["nirc_adaptive"].model_dump(mode="json"))
    assert job.spec == RENDERS["nirc_adaptive"] and job.params.nc == [8, 1]
    assert job.max_depth == -1 and RenderJob.parse(RENDERS["restir"]).max_depth == 2
    with pytest.raises(MethodError, match="nc"):
        RenderJob.parse(RENDERS["pt"].model_copy(update={"method": "nirc",
                                                         "params": {"nc": [0]}}))
    with pytest.raises(MethodError, match="rr_survival"):   # strict: text is not a number
        RenderJob.parse(RENDERS["pt"].model_copy(update={"params": {"rr_survival": "0.5"}}))


def test_derived_jobs_are_validated_and_keep_the_spec_in_step():
    job = RenderJob.parse(RENDERS["nirc_adaptive"])
    derived = job.with_params({"termination": "adaptive", "nc": [2, 1]})
    assert derived.params.nc == [2, 1] and derived.spec.params["nc"] == [2, 1]
    with pytest.raises(MethodError):
        job.with_params({"nc": [1000]})
    assert job.baseline().method == "pt" and job.baseline().max_depth == job.max_depth
    with pytest.raises(ValueError, match="dump"):
        RenderJob.of(job.spec, parse_params("nirc", {"nc": [4]}))


def test_the_executor_renders_and_stores_the_typed_parameters(mi, data_dir):
    """The executor takes the job's typed parameters, not its JSON: a job whose JSON
    says otherwise is rendered and stored with the typed values."""
    from jobs.protocol.executor import execute
    from jobs.protocol.spec import ReferenceSpec
    from jobs.record.config import Settings
    from jobs.record.db import open_store

    spec = RenderSpec(scene="cornell-box", resolution=8, seeds=2,
                      params={"max_depth": 3, "rr_survival": 0.9},
                      reference=ReferenceSpec(spp=64))
    job = RenderJob(spec, parse_params("pt", {"max_depth": 3, "rr_survival": 0.5}))
    settings = Settings()
    store = open_store(settings)
    run = store.get_run(execute(job, store, settings).run_id)
    store.close()
    assert run.params["rr_survival"] == 0.5


#: The modules below the entry points: none of them validates a method's parameters.
BELOW_THE_EDGES = ("jobs/protocol/executor.py", "jobs/protocol/calibration.py",
                   "jobs/protocol/references.py", "jobs/sweeps/snapshots.py",
                   "jobs/execution/queue.py", "jobs/ci/ci.py")


@pytest.mark.parametrize("path", BELOW_THE_EDGES)
def test_parameter_models_are_validated_only_at_the_entry_points(path):
    tree = ast.parse((ROOT / path).read_text())
    calls = [node for node in ast.walk(tree) if isinstance(node, ast.Call)]
    names = {getattr(call.func, "id", getattr(call.func, "attr", None)) for call in calls}
    assert not names & {"parse_params", "model_validate", "model_validate_json"}, path
    assert not any(getattr(call.func, "id", None) == "RenderSpec" for call in calls), path


def test_the_keys_before_the_metric_version_bump_are_unchanged(monkeypatch):
    """Only the metric version moved the keys: at version 2 they are those from before
    (so a change of what is hashed cannot hide behind the bump)."""
    import jobs.protocol.references as references
    import jobs.protocol.spec as spec
    import jobs.protocol.versions as versions

    for module in (references, spec, versions):
        monkeypatch.setattr(module, "METRIC_VERSION", 2)
    assert _keys() == GOLDEN_METRIC_VERSION_2


#: The keys of N_c sweep points, computed by the code before the N_c sweep was a
#: parameter sweep (its own study, with a top-level termination): by (sweep, N_c).
N_C_SWEEPS = {"sph": SWEEPS["nc"], "default": SweepSpec(scene="cornell-box", nc=[3, 8],
                                                          train_frames=7)}
N_C_POINT_KEYS = {("sph", 1): "d3f7211f7832043ddecebb990e120dae",
                  ("sph", 2): "e76645835726dfd85140de55892987c9",
                  ("default", 3): "7793cf2ea19b503641e9089eb6fcbf57",
                  ("default", 8): "fb39d4caf7cb0527a88f8434f2e627fd"}


def _nc_point_keys() -> dict[tuple[str, int], str]:
    from jobs.sweeps.sweep import _Sweep

    keys = {}
    for name, spec in N_C_SWEEPS.items():
        sweep = object.__new__(_Sweep)   # its keys only: no reference is prepared
        sweep.spec, sweep.base, sweep.device_key = spec, spec.base_render_spec(), "device"
        sweep.prepared = SimpleNamespace(scene=SimpleNamespace(fingerprint="fingerprint"),
                                         reference=SimpleNamespace(key="refkey"))
        for nc in spec.parameter.values:
            job = sweep.point_job("nirc", spec.parameter_point("nirc", nc))
            keys[(name, nc)] = sweep.parameter_point_key(job)
    return keys


def test_an_nc_sweep_finds_its_points_under_their_keys_from_before(monkeypatch):
    assert _nc_point_keys() == N_C_POINT_KEYS
    # Planted: keyed as any other parameter sweep's points, none is found.
    monkeypatch.setattr(SweepSpec, "is_nc_sweep", property(lambda self: False))
    assert not set(_nc_point_keys().values()) & set(N_C_POINT_KEYS.values())


def test_the_nc_sweep_form_is_a_parameter_sweep_over_nc():
    from jobs.protocol.spec import ParameterSweep

    given = SweepSpec(scene="cornell-box", methods=["nirc"], params={"sph_c": 0.02,
                                                                       "termination": "sph"},
                      parameter=ParameterSweep(name="nc", values=[1, 2]))
    assert SWEEPS["nc"] == given and SWEEPS["nc"].is_nc_sweep
    assert SweepSpec.model_validate(given.model_dump(mode="json")) == given
    # The stored form of every other sweep keeps the default policy it held (its key).
    assert SWEEPS["eps"].model_dump(mode="json")["termination"] == \
        parse_params("nirc", {}).termination
    assert "termination" not in given.model_dump(mode="json")


#: A grid-cache policy's parameters as stored by the code before the policies' models were
#: typed: a whole number given for a float parameter as given.
GOLDEN_POLICY_PARAMS = {
    '{"threshold": 1}': "913d2ae0d9612304015b621350dff41bfbdb61605726da1bfde66bf563144fda",
    '{"threshold": 2, "relative": false}':
        "8fb3bd5e5e23ba9c72ef83d52081313907b0e12a4906214073c68b72519ade8a",
}


def test_a_whole_number_for_a_float_policy_parameter_dumps_as_given():
    import json

    def key(given: dict) -> str:
        params = parse_params("grid-cache", {"termination": "var-bound",
                                             "termination_params": given})
        return digest(params.model_dump(mode="json")["termination_params"])

    assert {text: key(json.loads(text)) for text in GOLDEN_POLICY_PARAMS} == GOLDEN_POLICY_PARAMS
    # Planted: dumped as the float it equals, the key is another.
    assert key({"threshold": 1.0}) != GOLDEN_POLICY_PARAMS['{"threshold": 1}']
    with pytest.raises(MethodError, match="threshold"):   # still checked as a float
        key({"threshold": -1})
