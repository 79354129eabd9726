"""The CLI end to end, in subprocesses: what a user types and what they see."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest


def run_cli(*args: str, data_dir: Path, env: dict[str, str] | None = None,
            timeout: float = 600) -> subprocess.CompletedProcess:
    full_env = {**os.environ, "NIRC_BENCH_DATA_DIR": str(data_dir), **(env or {})}
    full_env.pop("NIRC_BENCH_DEBUG", None)
    return subprocess.run([sys.executable, "-m", "service", *args], capture_output=True,
                          text=True, env=full_env, timeout=timeout)


def started_together(calls: Sequence[tuple[str, ...]], folder: Path
                     ) -> Iterator[dict[tuple[str, ...], Future]]:
    """Each of ``calls`` run as :func:`run_cli` (its own data folder under ``folder``), a
    few at a time, from now on: the calls of the error cases share nothing, and each is
    a process that spends seconds starting before it fails. Yields {call: its future}."""
    with ThreadPoolExecutor(max_workers=4) as pool:
        yield {call: pool.submit(run_cli, *call, data_dir=folder / str(i))
               for i, call in enumerate(calls)}


def assert_clean_error(proc: subprocess.CompletedProcess, *fragments: str) -> None:
    """Non-zero exit, no traceback, and a message that says what is wrong."""
    assert proc.returncode != 0, proc.stdout
    assert "Traceback" not in proc.stderr + proc.stdout
    text = (proc.stderr + proc.stdout).lower()
    for fragment in fragments:
        assert fragment.lower() in text, proc.stderr


def test_scenes_json_lists_every_builtin(tmp_path):
    proc = run_cli("scenes", "--json", "--res", "16", data_dir=tmp_path)
    assert proc.returncode == 0, proc.stderr
    scenes = {s["name"]: s for s in json.loads(proc.stdout)}
    assert set(scenes) == {"cornell-box", "cornell-glossy", "door", "corridor", "sky",
                           "many-lights", "many-lights-300", "white-room"}
    assert scenes["sky"]["features"]["has_envmap"]
    assert len({s["fingerprint"] for s in scenes.values()}) == len(scenes)


def test_unknown_scene_is_a_clear_error(tmp_path):
    proc = run_cli("render", "--scene", "no-such-scene", data_dir=tmp_path)
    assert_clean_error(proc, "no-such-scene", "cornell-box")


def test_malformed_xml_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<scene version='3.0.0'><shape type='sphere'></scene>")
    proc = run_cli("render", "--scene", str(bad), "--res", "8", data_dir=tmp_path)
    assert_clean_error(proc, "bad.xml")


def test_a_method_that_does_not_apply_is_refused_before_its_reference(tmp_path):
    """One line, exit 2, and no reference rendered for a job that cannot run (before: the
    reference first, 241 s at --res 64 --ref-spp 65536, then the refusal)."""
    proc = run_cli("render", "--scene", "cornell-glossy", "--method", "grid-cache", "--res",
                   "8", "--ref-spp", "64", data_dir=tmp_path)
    assert_clean_error(proc, "grid-cache", "does not apply", "glossy")
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert proc.stderr.startswith("nirc-bench: error: method 'grid-cache' does not apply")
    assert not list((tmp_path / "references").glob("*.exr"))


OUT_OF_RANGE = [
    (("--res", "0"), "--res"),
    (("--spp", "-3"), "--spp"),
    (("--seeds", "0"), "--seeds"),
    (("--param", "max_depth=0"), "max_depth"),
    (("--param", "rr_survival=1.5"), "rr_survival"),
    (("--method", "magic"), "unknown method"),
    # restir-di renders direct light only: a longer path is refused, not rendered.
    (("--method", "restir-di", "--max-depth", "-1"), "max_depth"),
]

BAD_SWEEP = [
    (("--eps", "0.05:1.0:0"), "step"),
    (("--eps", "1.0:0.05"), "eps"),
    (("--eps", "a:b"), "not a number"),
    (("--eps", "0.5", "--methods", "nirc,pt"), "methods"),
    (("--nc", "0:4"), "nc"),
    ((), "--eps"),
]


#: The report's PT calibration bounds (a typo names the candidates instead of rendering).
BAD_REPORT = [
    (("--strongest", "pt,pt-powr"), "pt-power"),
    (("--max-pt-spp", "0"), "--max-pt-spp"),
]


def _report_call(args: tuple[str, ...]) -> tuple[str, ...]:
    return ("report", "--scene", "cornell-box", *args)


def _render_call(args: tuple[str, ...]) -> tuple[str, ...]:
    return ("render", "--scene", "cornell-box", *args)


def _sweep_call(args: tuple[str, ...]) -> tuple[str, ...]:
    return ("sweep", "--scene", "cornell-box", *args)


@pytest.fixture(scope="module")
def error_calls(tmp_path_factory) -> Iterator[dict[tuple[str, ...], Future]]:
    calls = ([_render_call(a) for a, _ in OUT_OF_RANGE] + [_sweep_call(a) for a, _ in BAD_SWEEP]
             + [_report_call(a) for a, _ in BAD_REPORT])
    yield from started_together(calls, tmp_path_factory.mktemp("errors"))


@pytest.mark.parametrize("args, fragment", OUT_OF_RANGE)
def test_out_of_range_numbers_are_clear_errors(error_calls, args, fragment):
    proc = error_calls[_render_call(args)].result()
    assert_clean_error(proc, fragment)


@pytest.mark.parametrize("args, fragment", BAD_REPORT)
def test_bad_report_bounds_are_clear_errors(error_calls, args, fragment):
    assert_clean_error(error_calls[_report_call(args)].result(), fragment)


def test_missing_libllvm_is_a_clear_error(tmp_path):
    env = {"NIRC_BENCH_LLVM_SEARCH": str(tmp_path / "nowhere"), "DRJIT_LIBLLVM_PATH": ""}
    proc = run_cli("scenes", data_dir=tmp_path, env=env)
    assert_clean_error(proc, "libllvm", "libllvm19")


def test_a_missing_native_library_is_a_clear_error(tmp_path):
    """Dr.Jit's extension cannot load libatomic: it raises a NameError while handling the
    ImportError (as drjit/__init__.py does); the CLI says which library, in one line."""
    fake = tmp_path / "fake" / "drjit"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text(
        "try:\n"
        "    raise ImportError('libatomic.so.1: cannot open shared object file: '\n"
        "                      'No such file or directory')\n"
        "except ImportError:\n"
        "    filename = _drjit_ext.__file__\n")
    env = {"PYTHONPATH": os.pathsep.join([str(fake.parent), os.environ.get("PYTHONPATH", "")])}
    proc = run_cli("scenes", data_dir=tmp_path, env=env)
    assert_clean_error(proc, "libatomic.so.1", "apt-get install libatomic1")
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1


def test_corrupt_and_mismatched_exr_are_clear_errors(tmp_path):
    from metrics.imageio import write_exr

    corrupt = tmp_path / "corrupt.exr"
    corrupt.write_bytes(b"\x76\x2f\x31\x01" + os.urandom(200))
    small, large = tmp_path / "small.exr", tmp_path / "large.exr"
    write_exr(small, np.ones((4, 4, 3), np.float32))
    write_exr(large, np.ones((8, 8, 3), np.float32))
    assert_clean_error(run_cli("evaluate", "-r", str(small), "-i", str(corrupt), data_dir=tmp_path),
                       "corrupt.exr")
    assert_clean_error(run_cli("evaluate", "-r", str(small), "-i", str(large), data_dir=tmp_path),
                       "shape")
    assert_clean_error(run_cli("evaluate", "-r", str(small), "-i", str(tmp_path / "none.exr"),
                               data_dir=tmp_path), "none.exr")


@pytest.mark.slow
def test_render_reference_evaluate_round_trip(tmp_path):
    out = tmp_path / "out"
    args = ("render", "--scene", "cornell-box", "--res", "16", "--spp", "1", "--frames", "2",
            "--seeds", "3", "--ref-spp", "256", "--json")
    first = run_cli(*args, "--out", str(out), data_dir=tmp_path)
    assert first.returncode == 0, first.stderr
    summary = json.loads(first.stdout)
    assert summary["reference"]["rendered_now"] is True
    metrics = summary["metrics"]
    assert metrics["k"] == 3 and metrics["mrse_mean"] > 0
    assert metrics["mrse_ci95"][0] <= metrics["mrse_mean"] <= metrics["mrse_ci95"][1]
    assert summary["quality"]["finite"] is True
    assert (out / "summary.json").is_file() and (out / "reference.exr").is_file()
    assert (out / "image_seed0.exr").is_file() and (out / "preview_seed0.png").is_file()
    assert (out / "convergence.png").is_file()  # frames > 1: error over frames (Fig. 10)

    second = run_cli(*args, data_dir=tmp_path)
    assert second.returncode == 0, second.stderr
    assert json.loads(second.stdout)["reference"]["rendered_now"] is False

    ref = run_cli("reference", "--scene", "cornell-box", "--res", "16", "--spp", "256",
                  "--out", str(tmp_path / "ref.exr"), "--json", data_dir=tmp_path)
    assert ref.returncode == 0, ref.stderr
    assert json.loads(ref.stdout)["reused"] is True

    evaluated = run_cli("evaluate", "-r", str(tmp_path / "ref.exr"),
                        "-i", str(out / "image_seed0.exr"), "--json", data_dir=tmp_path)
    assert evaluated.returncode == 0, evaluated.stderr
    values = json.loads(evaluated.stdout)
    assert values["mrse"] == pytest.approx(summary["per_seed"][0]["mrse"], rel=1e-5)


def test_render_takes_the_methods_own_depth_unless_given(tmp_path):
    # restir-di renders direct light only (max_depth 2): no --max-depth needed, and its
    # reference is the depth-2 one an explicit --max-depth 2 reuses (a longer one is
    # refused: OUT_OF_RANGE).
    args = ("render", "--scene", "many-lights", "--method", "restir-di", "--res", "8",
            "--seeds", "2", "--ref-spp", "64", "--json")
    first = run_cli(*args, data_dir=tmp_path)
    assert first.returncode == 0, first.stderr
    assert json.loads(first.stdout)["reference"]["rendered_now"] is True
    again = run_cli(*args, "--max-depth", "2", data_dir=tmp_path)
    assert again.returncode == 0, again.stderr
    assert json.loads(again.stdout)["reference"]["rendered_now"] is False


#: A small sweep; its equal-time probes count on a loaded machine (the test machine is
#: shared: the tests check what is recorded, not the machine's quiet).
SWEEP_SMALL = ("--scene", "cornell-box", "--res", "8", "--seeds", "2", "--train-frames", "2",
               "--v1-spp", "4", "--ref-spp", "64", "-p", 'cache={"batch_size": 1024}',
               "-p", "min_train_paths=1024", "--allow-loaded")


@pytest.mark.parametrize("args, fragment", BAD_SWEEP)
def test_bad_sweep_arguments_are_clear_errors(error_calls, args, fragment):
    proc = error_calls[_sweep_call(args)].result()
    assert_clean_error(proc, fragment)
    assert proc.returncode == 2


def test_sweep_prints_the_table_writes_plots_and_reuses_everything(tmp_path):
    out = tmp_path / "out"
    proc = run_cli("sweep", *SWEEP_SMALL, "--eps", "0.5:1.0", "--nc", "1,2", "--out", str(out),
                   data_dir=tmp_path / "data")
    assert proc.returncode == 0, proc.stderr
    assert "NIRC equal time" in proc.stdout and "% IR" in proc.stdout
    assert (out / "sweep_fig13.png").is_file() and (out / "convergence_fig10.png").is_file()
    again = run_cli("sweep", *SWEEP_SMALL, "--eps", "0.5:1.0", "--nc", "1,2", "--json",
                    data_dir=tmp_path / "data")
    assert again.returncode == 0, again.stderr
    result = json.loads(again.stdout)
    assert result["work"]["points_rendered"] == 0 and result["work"]["snapshots_trained"] == 0
    assert len(result["rows"]) == 6


def test_server_errors_are_clear(tmp_path):
    unreachable = run_cli("render", "--scene", "cornell-box", "--server", "http://127.0.0.1:9",
                          data_dir=tmp_path)
    assert_clean_error(unreachable, "cannot reach the service")
    assert unreachable.returncode == 2
    with_out = run_cli("sweep", "--scene", "cornell-box", "--eps", "0.5", "--server",
                       "http://127.0.0.1:9", "--out", str(tmp_path / "x"), data_dir=tmp_path)
    assert_clean_error(with_out, "--out")


@pytest.mark.parametrize("text, name, values", [
    ("sph_c=0.01,0.1,1,10", "sph_c", [0.01, 0.1, 1.0, 10.0]),
    ("unbiased_every=4:16:4", "unbiased_every", [4, 8, 12, 16]),
    ("self_training=true,false", "self_training", [True, False]),
    ("rr_mode=fixed,throughput", "rr_mode", ["fixed", "throughput"]),
])
def test_sweep_option_takes_values_or_a_range(text, name, values):
    from service.cli import _parse_sweep

    parsed = _parse_sweep(text)
    assert (parsed.name, parsed.values) == (name, values)
    assert [type(v) for v in parsed.values] == [type(v) for v in values]
