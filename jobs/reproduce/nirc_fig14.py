"""[DKHD24] Fig. 14: the signed squared difference of the per-pixel standard deviations
of MC (path tracing) and MLMC (unbiased NIRC) for direct illumination, sigma_PT² -
sigma_NIRC², drawn as a diverging map (positive: MLMC's deviation is lower).

Ours: `pt` (no roulette) and unbiased `nirc` on sky at ``max_depth`` 2 (direct light
only), K seeds each; per pixel the seeds' sample variance of the render divided by the
reference's R² + eps (metrics/pixel_maps.py, the map behind rVar), averaged over RGB:
both methods share the reference, so the difference of the two maps is sigma_PT² -
sigma_NIRC² in the reference's relative units. The claim (MLMC works best in smooth
regions, fails near occlusion) is judged by the ratio of the mean variances (the share of
pixels where MLMC's variance is lower beside it), in the smooth pixels and at the edges: the
quarter of the pixels where the reference's log-luminance changes most from a neighbour
(shadow and occlusion boundaries), of the pixels with any variance (not the bare sky).
Intervals: a bootstrap over each method's seeds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from jobs.reproduce.measure import sweep
from jobs.reproduce.registry import Budget, Context, FigureSpec, register
from jobs.reproduce.results import Estimate, Point, Reproduction, Verdict

SCENE = "sky"
MAX_DEPTH = 2
PRETRAIN_PER_FRAME = 8
#: The share of pixels called edges: the steepest quarter of the reference.
EDGE_QUANTILE = 0.75
BOOTSTRAP_DRAWS = 400
EPS = 1e-2
QUANTITIES = {"variance_ratio": "sigma_PT² / sigma_NIRC² (region means)",
              "share_lower": "share of pixels with MLMC's variance lower",
              "mean_difference": "mean of sigma_PT² - sigma_NIRC² (relative)"}
REGIONS = ("all", "smooth", "edge")
BOOTSTRAP_NOTE = (f"95 % interval: percentile bootstrap over the seeds ({BOOTSTRAP_DRAWS} "
                  "draws, each method's K renders resampled with replacement)")

QUICK_WHY = ("--quick: 32x32, K = 8 seeds of F = 4 frames, NIRC after 32 pre-training "
             "frames (the paper: 1080p after thousands of frames on a GPU)")
FULL_WHY = "--full: 128x128, K = 8, F = 16 after 128 pre-training frames"
QUICK = Budget(resolution=32, seeds=8, frames=4, ref_spp=1024, grid_preset="—", why=QUICK_WHY)
FULL = Budget(resolution=128, seeds=8, frames=16, ref_spp=4096, grid_preset="—",
              why=FULL_WHY)


def seed_images(ctx: Context, run: Any) -> tuple[list[np.ndarray], np.ndarray]:
    """(each seed's stored render, the reference) of a stored run."""
    from jobs.record.artifacts import ArtifactStore
    from metrics.imageio import read_exr

    artifacts = ArtifactStore(ctx.settings.artifacts_dir)
    images = [read_exr(artifacts.path_of(a.path)) for seed in run.seed_results
              for a in seed.artifacts if a.kind == "image"]
    return images, read_exr(ctx.settings.references_dir / run.reference.image_path)


def variance_map(images: list[np.ndarray], ref: np.ndarray) -> np.ndarray:
    """Per pixel: the seeds' sample variance over (R² + eps), the mean over RGB."""
    from metrics.pixel_maps import relative_bias_variance_maps

    _bias, spread = relative_bias_variance_maps(images, ref, EPS)
    return spread.reshape(spread.shape[0], spread.shape[1], -1).mean(axis=2)


def edge_mask(ref: np.ndarray, estimated: np.ndarray) -> np.ndarray:
    """Of the ``estimated`` pixels, the quarter whose log-luminance differs most from a
    neighbour's."""
    luminance = np.log(np.asarray(ref, dtype=np.float64).reshape(*ref.shape[:2], -1)
                       .mean(axis=2) + EPS)
    rows, cols = np.gradient(luminance)
    steepness = np.hypot(rows, cols)
    if not estimated.any():
        return estimated
    return estimated & (steepness > np.quantile(steepness[estimated], EDGE_QUANTILE))


def region_masks(pt_map: np.ndarray, nirc_map: np.ndarray,
                 ref: np.ndarray) -> dict[str, np.ndarray]:
    """The estimated pixels (finite, some variance in either method: not the bare sky)
    and of them the smooth and the edge pixels."""
    estimated = np.isfinite(pt_map) & np.isfinite(nirc_map) & (pt_map + nirc_map > 0)
    edges = edge_mask(ref, estimated)
    return {"all": estimated, "smooth": estimated & ~edges, "edge": edges}


def region_statistics(pt_map: np.ndarray, nirc_map: np.ndarray,
                      masks: dict[str, np.ndarray]) -> dict[str, tuple[float, float, float]]:
    """Per region: (ratio of the mean variances PT / NIRC, share of pixels where MLMC's
    variance is lower, mean difference)."""
    out = {}
    for region, mask in masks.items():
        pt, nirc = pt_map[mask], nirc_map[mask]
        if not pt.size:
            out[region] = (float("nan"),) * 3
            continue
        ratio = float(pt.mean() / nirc.mean()) if nirc.mean() > 0 else float("inf")
        out[region] = (ratio, float((pt > nirc).mean()), float((pt - nirc).mean()))
    return out


def compare(pt: list[np.ndarray], nirc: list[np.ndarray], ref: np.ndarray,
            seed: int = 0) -> tuple[dict[str, dict[str, Estimate]], np.ndarray, np.ndarray]:
    """Per region its share and mean difference with bootstrap intervals, the difference
    map sigma_PT² - sigma_NIRC² and the edge mask."""
    pt_map, nirc_map = variance_map(pt, ref), variance_map(nirc, ref)
    masks = region_masks(pt_map, nirc_map, ref)
    found = region_statistics(pt_map, nirc_map, masks)
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(BOOTSTRAP_DRAWS):
        pick_pt = [pt[i] for i in rng.integers(len(pt), size=len(pt))]
        pick_nirc = [nirc[i] for i in rng.integers(len(nirc), size=len(nirc))]
        draws.append(region_statistics(variance_map(pick_pt, ref),
                                       variance_map(pick_nirc, ref), masks))
    estimates: dict[str, dict[str, Estimate]] = {}
    for region in REGIONS:
        estimates[region] = {}
        for index, key in enumerate(QUANTITIES):
            sample = np.array([d[region][index] for d in draws])
            sample = sample[np.isfinite(sample)]
            interval = (None if not sample.size else
                        [float(v) for v in np.percentile(sample, [2.5, 97.5])])
            estimates[region][key] = Estimate(value=found[region][index], ci95=interval,
                                              note=BOOTSTRAP_NOTE)
    difference = np.where(masks["all"], pt_map - nirc_map, np.nan)
    return estimates, difference, masks["edge"]


def measure(ctx: Context) -> Reproduction:
    b = ctx.budget
    [(_pt_row, pt_run)] = sweep(ctx, SCENE, "pt", "rr_survival", [1.0], {},
                                max_depth=MAX_DEPTH)
    [(_nirc_row, nirc_run)] = sweep(ctx, SCENE, "nirc", "pretrain_frames",
                                    [PRETRAIN_PER_FRAME * b.frames],
                                    {"estimator": "unbiased"}, max_depth=MAX_DEPTH)
    pt_images, ref = seed_images(ctx, pt_run)
    nirc_images, _ref = seed_images(ctx, nirc_run)
    estimates, difference, edges = compare(pt_images, nirc_images, ref)
    points = [Point(scene=SCENE, series=f"{region} pixels", x=float(index),
                    values=estimates[region], run_id=nirc_run.id)
              for index, region in enumerate(REGIONS)]
    return Reproduction(
        paper="nirc", figure="fig14", title="[DKHD24] Fig. 14: sigma_PT² - sigma_NIRC², "
                                            "direct illumination",
        mode="", settings={"resolution": f"{b.resolution}x{b.resolution}", "seeds K": b.seeds,
                           "frames F": b.frames, "max depth": MAX_DEPTH,
                           "NIRC pre-training frames": PRETRAIN_PER_FRAME * b.frames,
                           "runs (pt, nirc)": f"{pt_run.id}, {nirc_run.id}", "why": b.why},
        x_label="region (0 all, 1 smooth, 2 edge)", quantities=QUANTITIES, points=points,
        verdicts=[verdict(estimates)], images={"difference": difference, "edges": edges},
        notes=["sigma²: the K seeds' per-pixel sample variance of the render over the "
               "reference's R² + eps (eps 1e-2), the mean over RGB (module doc)",
               "edge pixels: the quarter where the reference's log-luminance is steepest",
               "the paper's foliage is not built in: sky's courtyard (sun shadows, arcade, "
               "pillars) holds the occlusion boundaries"])


def verdict(estimates: dict[str, dict[str, Estimate]]) -> Verdict:
    """Holds when MLMC lowers the variance in the smooth pixels (sigma_PT² / sigma_NIRC²
    of the region's means: interval above 1) by more than at the edges (intervals apart);
    does not hold when the smooth ratio's interval lies below 1 or below the edges';
    else not comparable. The share of pixels is reported, not judged: with K seeds each
    pixel's variance is noisy, which pulls the share toward 1/2."""
    claim = "MLMC lowers the variance in smooth regions and can fail near occlusion"
    smooth, edge = estimates["smooth"], estimates["edge"]
    ratio_smooth, ratio_edge = smooth["variance_ratio"], edge["variance_ratio"]
    text = (f"sigma_PT² / sigma_NIRC² smooth {ratio_smooth.text()}, edge "
            f"{ratio_edge.text()}; share with MLMC lower: smooth "
            f"{smooth['share_lower'].text()}, edge {edge['share_lower'].text()}")
    if ratio_smooth.ci95 is None or ratio_edge.ci95 is None:
        return Verdict(claim=claim, verdict="not comparable", reason=f"no interval; {text}")
    if ratio_smooth.ci95[0] > max(1.0, ratio_edge.ci95[1]):
        return Verdict(claim=claim, verdict="holds",
                       reason=f"lower in the smooth pixels, less so at the edges; {text}")
    if ratio_smooth.ci95[1] < 1.0 or ratio_smooth.ci95[1] < ratio_edge.ci95[0]:
        return Verdict(claim=claim, verdict="does not hold",
                       reason=f"not lower in the smooth pixels, or lower still at the "
                              f"edges; {text}")
    return Verdict(claim=claim, verdict="not comparable", reason=f"intervals overlap; {text}")


def draw(reproduction: Reproduction, path: Path) -> Path:
    """The diverging map of sigma_PT² - sigma_NIRC² (symmetric log scale; red: MLMC lower)
    beside the edge mask; a table read back without its maps draws the shares."""
    from matplotlib.colors import SymLogNorm

    from jobs.views.plots import new_figure, save_png

    if "difference" not in reproduction.images:
        from jobs.reproduce.plot import Panel, plot_panels
        return plot_panels(reproduction, [Panel(k, v, log_y=False)
                                          for k, v in QUANTITIES.items()], path, log_x=False)
    difference = reproduction.images["difference"]
    figure, (left, right) = new_figure(1, 2, reproduction.title, figsize=(9.2, 4.4))
    finite = np.abs(difference[np.isfinite(difference)])
    scale = float(finite.max()) if finite.size and finite.max() > 0 else 1.0
    shown = left.imshow(difference, cmap="RdBu_r",
                        norm=SymLogNorm(linthresh=scale * 1e-3, vmin=-scale, vmax=scale))
    figure.colorbar(shown, ax=left, shrink=0.8)
    left.set_title("sigma_PT² - sigma_NIRC² (red: MLMC lower)", fontsize="medium")
    right.imshow(reproduction.images["edges"], cmap="gray")
    right.set_title("edge pixels (white)", fontsize="medium")
    for ax in (left, right):
        ax.set_axis_off()
    return save_png(figure, path)


FIGURE = register(FigureSpec("nirc", "fig14", "Signed squared difference of the per-pixel "
                             "standard deviations of PT and unbiased NIRC for direct "
                             "illumination on sky, by smooth and edge pixels",
                             {"quick": QUICK, "full": FULL}, measure, draw))
