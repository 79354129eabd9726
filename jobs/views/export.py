"""A stored run's files under readable names: what ``render --out`` and ``runs export`` write.

Everything comes from the store (the run's rows, its artifacts, its reference), so a
run exported long after it was rendered gives the same folder as ``render --out``:

- ``reference.exr``, ``reference.variance.exr``, ``reference_preview.png``;
- per seed ``image_seed<k>.exr`` and, where stored, ``preview_seed<k>.png``,
  ``error_map_seed<k>.png`` and the kept frames ``frame<n>_seed<k>.exr``;
- the run's ``rel_bias_map.exr`` and ``rel_variance_map.exr`` (runs of 2+ seeds);
- ``convergence.png`` (MRSE over frames of every seed; the dashboard's chart of it,
  drawn by vl-convert) when the run has more than one frame;
- ``summary.json``: the run as ``render --json`` prints it.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from jobs.protocol.results import RunResultDetail
from jobs.record.artifacts import ArtifactStore
from jobs.record.config import Settings
from metrics.imageio import read_exr, write_png
from metrics.preview import tonemap_preview


def export_run(run: Any, summary: dict[str, Any], settings: Settings,
               out_dir: Path) -> dict[str, str]:
    """Write the files of the stored ``run`` (loaded as ``Store.get_run`` loads it) into
    ``out_dir``, with ``summary`` as summary.json; the written files by name."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    reference = run.reference
    if reference is not None:
        files["reference"] = out_dir / "reference.exr"
        files["reference_variance"] = out_dir / "reference.variance.exr"
        files["reference_preview"] = out_dir / "reference_preview.png"
        shutil.copyfile(settings.references_dir / reference.image_path, files["reference"])
        shutil.copyfile(settings.references_dir / reference.variance_path,
                        files["reference_variance"])
        write_png(files["reference_preview"], tonemap_preview(read_exr(files["reference"])))
    artifacts = ArtifactStore(settings.artifacts_dir)
    seed_of = {result.id: result.seed for result in run.seed_results}
    for artifact in run.artifacts:
        seed = seed_of.get(artifact.seed_result_id)
        suffix = Path(artifact.path).suffix
        name = f"{artifact.kind}_seed{seed}{suffix}" if seed is not None \
            else f"{artifact.kind}{suffix}"
        files[name] = out_dir / name
        shutil.copyfile(artifacts.path_of(artifact.path), files[name])
    # Error over frames (the NIRC paper's Fig. 10), as the dashboard draws it. Altair
    # and its PNG renderer take ~0.6 s to import: only a run that is exported pays it.
    from jobs.views.charts import chart_png, convergence_chart

    convergence = convergence_chart(RunResultDetail.of(run).model_dump(mode="json"))
    if convergence is not None:
        files["convergence"] = chart_png(convergence, out_dir / "convergence.png")
    files["summary"] = out_dir / "summary.json"
    files["summary"].write_text(json.dumps(summary, indent=2, default=str))
    return {name: str(path) for name, path in files.items()}
