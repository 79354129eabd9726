"""What a process loads when it starts: a render process (jobs.execution.runner and
the modules its jobs run through) and the CLI up to planning a ``pareto`` call load
neither the plotting libraries nor SciPy's statistics. Each costs 0.5-1 s to import,
paid by every render process, worker and CLI command that starts; the functions that
plot, export or fit import them where they are used."""

from __future__ import annotations

import json
import subprocess
import sys

from tests.test_layers import ROOT

HEAVY = ("matplotlib", "altair", "vl_convert", "scipy.stats")
#: A render process's imports (jobs.execution.runner: a queued job's run), then the CLI's.
STARTUP = """
import json, sys
import jobs.execution.runner
import jobs.execution.queued
from jobs.protocol.executor import execute
from jobs.protocol.job import RenderJob
from jobs.protocol.spec import SweepSpec
from jobs.sweeps.sweep import run_stage, run_sweep
render_process = sorted(m for m in HEAVY if m in sys.modules)
import service.cli
from jobs.pareto.plan import ParetoSpec, plan
plan(ParetoSpec(scene="cornell-box"))
print(json.dumps([render_process, sorted(m for m in HEAVY if m in sys.modules)]))
"""


def test_a_render_process_and_the_cli_start_without_plotting_or_statistics():
    proc = subprocess.run([sys.executable, "-c", f"HEAVY = {HEAVY!r}\n{STARTUP}"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    render_process, cli = json.loads(proc.stdout.strip().splitlines()[-1])
    assert render_process == [], f"a render process imports {render_process} at start"
    assert cli == [], f"the CLI imports {cli} before it has checked a pareto call's options"
