"""PNG plots of sweeps and convergence: valid files, robust to bad values, atomic writes."""

import math
from pathlib import Path
from typing import Any

import pytest
from matplotlib.colors import to_hex
from matplotlib.figure import Figure
from PIL import Image

from jobs.views import plots
from jobs.views.chart_styles import ENVELOPE_STYLE, ENVELOPE_WIDTH, FAMILY_COLOURS, FRONT_COLOUR
from jobs.views.plots import plot_convergence, plot_pareto, plot_sweep

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def sweep_row(series: str, pct: float | None, **metrics: Any) -> dict[str, Any]:
    row = {
        "series": series,
        "eps": 0.1,
        "ir_bounces_pct": pct,
        "mrse": 0.02,
        "mrse_ci95": [0.015, 0.025],
        "flip": 0.1,
        "rbias2": 1e-3,
        "rvar": 1e-2,
        "ms_frame": 8.0,
    }
    return row | metrics


def assert_png(path: Path, min_size: tuple[int, int] = (400, 300)) -> None:
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    with Image.open(path) as image:
        image.verify()
    with Image.open(path) as image:
        assert image.format == "PNG"
        assert image.width >= min_size[0] and image.height >= min_size[1]


def assert_no_temp_files(folder: Path) -> None:
    assert [p.name for p in folder.iterdir() if p.name.startswith(".")] == []


@pytest.fixture
def figures(monkeypatch: pytest.MonkeyPatch) -> list[Figure]:
    """The figures the plot functions save, for checking what was drawn."""
    saved: list[Figure] = []
    save = plots.save_png

    def recording_save(figure: Figure, path: Path) -> Path:
        saved.append(figure)
        return save(figure, path)

    monkeypatch.setattr(plots, "save_png", recording_save)
    return saved


def assert_y_label_inside(figure: Figure, text: str) -> None:
    """Every panel's y label says ``text`` and lies inside the saved figure."""
    renderer = figure.canvas.get_renderer()
    for ax in figure.axes:
        assert text in ax.get_ylabel()
        extent = ax.yaxis.label.get_window_extent(renderer)
        assert extent.x0 >= 0 and extent.x1 <= figure.bbox.width, (extent, figure.bbox)


def panel_texts(figure: Figure) -> list[str]:
    return [text.get_text() for ax in figure.axes for text in ax.texts]


def test_sweep_writes_png(tmp_path: Path, figures: list[Figure]) -> None:
    methods = {"NIRC": "nirc", "NRC": "nrc", "NIRC equal time": "nirc", "ours": None}
    rows = [
        sweep_row(series, pct, method=method)
        for series, method in methods.items()
        for pct in (80.0, 0.0, 40.0)
    ]
    path = tmp_path / "nested" / "dir" / "sweep.png"
    assert plot_sweep(rows, path, "Equal-bias sweep") == path
    assert_png(path, min_size=(900, 700))
    assert_no_temp_files(path.parent)

    (figure,) = figures
    assert figure.get_suptitle() == "Equal-bias sweep"
    mrse, flip, rbias2, rvar = figure.axes
    assert [ax.get_yscale() for ax in (mrse, flip, rbias2, rvar)] == ["log", "linear", "log", "log"]
    assert mrse.get_xlabel() == "% indirect-radiance bounces"
    assert all(ax.get_ylabel() for ax in figure.axes)
    lines = {line.get_label(): line for line in mrse.get_lines()
             if not line.get_label().startswith("_")}
    assert list(lines["NIRC"].get_xdata()) == [0.0, 40.0, 80.0]  # sorted by x
    # The families' hues; NIRC's equal-time series a dashed shade of NIRC's.
    assert to_hex(lines["NIRC"].get_color()) == FAMILY_COLOURS["nirc"]
    assert to_hex(lines["NRC"].get_color()) == FAMILY_COLOURS["nrc"]
    assert lines["NIRC equal time"].get_linestyle() == "--"
    colours = [to_hex(line.get_color()) for line in lines.values()]
    assert len(set(colours)) == 4 and FRONT_COLOUR not in colours
    assert len(mrse.collections) == 4  # one set of CI error bars per series
    assert panel_texts(figure) == []
    assert len(figure.legends) == 1


def test_sweep_skips_missing_and_non_positive_values(tmp_path: Path, figures: list[Figure]) -> None:
    rows = [
        sweep_row("NIRC", 0.0, rbias2=-1e-4, mrse_ci95=None),
        sweep_row("NIRC", 25.0, rbias2=0.0, mrse=math.nan, flip=None),
        sweep_row("NIRC", 50.0, rbias2=math.inf, rvar=None, mrse_ci95=[math.nan, 0.1]),
        sweep_row("NIRC", 75.0, rbias2=2e-4, mrse_ci95=[0.03, 0.01]),  # inverted interval
        sweep_row("NIRC", None),  # no x: not plotted anywhere
        sweep_row(
            "NRC", 10.0, mrse=None, flip=math.nan, rbias2=-1.0, rvar=math.inf, mrse_ci95=None
        ),
    ]
    path = plot_sweep(rows, tmp_path / "sweep.png", "bad values")
    assert_png(path)

    mrse, flip, rbias2, rvar = figures[0].axes
    assert [list(line.get_xdata()) for line in mrse.get_lines()] == [[0.0, 50.0, 75.0]]
    assert len(mrse.collections) == 0  # no valid CI left to draw
    assert [list(line.get_xdata()) for line in flip.get_lines()] == [[0.0, 50.0, 75.0]]
    assert [list(line.get_ydata()) for line in rbias2.get_lines()] == [[2e-4]]
    # -1e-4, 0 and -1 are off the log axis; inf and the row without an x are not finite.
    assert [text.get_text() for text in rbias2.texts] == [
        "3 points <= 0 not shown\n2 points missing or not finite, not shown"]
    assert [list(line.get_xdata()) for line in rvar.get_lines()] == [[0.0, 25.0, 75.0]]
    assert [label.get_text() for label in figures[0].legends[0].get_texts()] == ["NIRC"]


def test_sweep_single_point_and_unplottable_series(tmp_path: Path, figures: list[Figure]) -> None:
    rows = [
        sweep_row("NIRC", 30.0, rbias2=-1e-4),
        sweep_row("NRC", None, mrse=None, flip=None, rbias2=None, rvar=None),
    ]
    assert_png(plot_sweep(rows, tmp_path / "sweep.png", "one point"))
    rbias2 = figures[0].axes[2]
    assert rbias2.texts[0].get_text() == ("no data\n1 point <= 0 not shown\n"
                                          "1 point missing or not finite, not shown")


def test_sweep_without_rows(tmp_path: Path, figures: list[Figure]) -> None:
    assert_png(plot_sweep([], tmp_path / "sweep.png", "empty"))
    assert panel_texts(figures[0]) == ["no data"] * 4
    assert figures[0].legends == []


def test_convergence_writes_png(tmp_path: Path, figures: list[Figure]) -> None:
    frames = list(range(1, 65))
    curves = {
        "NIRC": {
            "method": "nirc",
            "frame": frames,
            "frame_mrse": [0.05 for _ in frames],
            "accumulated_mrse": [0.05 / f for f in frames],
        },
        "NRC": {"method": "nrc", "frame": frames, "frame_mrse": [0.08 for _ in frames]},
    }
    path = tmp_path / "out" / "convergence.png"
    assert plot_convergence(curves, path, "Error over frames") == path
    assert_png(path, min_size=(700, 450))
    assert_no_temp_files(path.parent)

    (ax,) = figures[0].axes
    assert ax.get_yscale() == "log"
    styles = {
        line.get_label(): (line.get_linestyle(), to_hex(line.get_color()))
        for line in ax.get_lines()
    }
    assert styles == {
        "NIRC (per frame)": ("-", FAMILY_COLOURS["nirc"]),
        "NIRC (accumulated)": ("--", FAMILY_COLOURS["nirc"]),
        "NRC (per frame)": ("-", FAMILY_COLOURS["nrc"]),
    }
    assert_y_label_inside(figures[0], "MRSE")


def test_convergence_skips_bad_values(tmp_path: Path, figures: list[Figure]) -> None:
    curves = {
        "a": {
            "frame": [0, 1, 2, 3],
            "frame_mrse": [math.nan, 0.0, -1.0, 0.1],
            "accumulated_mrse": [math.inf, None, 0.2, 0.1],
        },
        "single": {"frame": [0], "frame_mrse": [0.3]},
        "nothing": {"frame": [], "frame_mrse": []},
    }
    assert_png(plot_convergence(curves, tmp_path / "c.png", "bad values"))
    (ax,) = figures[0].axes
    points = {line.get_label(): list(line.get_xdata()) for line in ax.get_lines()}
    assert points == {
        "a (per frame)": [3.0],
        "a (accumulated)": [2.0, 3.0],
        "single (per frame)": [0.0],
    }
    assert [text.get_text() for text in ax.texts] == [
        "2 points <= 0 not shown\n3 points missing or not finite, not shown"]


def test_convergence_without_curves(tmp_path: Path, figures: list[Figure]) -> None:
    assert_png(plot_convergence({}, tmp_path / "c.png", "empty"))
    assert panel_texts(figures[0]) == ["no data"]


def test_failed_write_keeps_old_file_and_leaves_no_temp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "c.png"
    path.write_bytes(b"previous plot")

    def broken_savefig(self: Figure, out: Any, **kwargs: Any) -> None:
        out.write(PNG_SIGNATURE)  # a partial file, then a crash
        raise RuntimeError("disk full")

    monkeypatch.setattr(Figure, "savefig", broken_savefig)
    with pytest.raises(RuntimeError, match="disk full"):
        plot_convergence({}, path, "crash")
    assert path.read_bytes() == b"previous plot"
    assert [p.name for p in tmp_path.iterdir()] == ["c.png"]


def test_overwrites_existing_plot(tmp_path: Path) -> None:
    path = tmp_path / "c.png"
    path.write_bytes(b"stale")
    plot_convergence({"x": {"frame": [1, 2], "frame_mrse": [0.1, 0.05]}}, path, "again")
    assert_png(path)
    assert [p.name for p in tmp_path.iterdir()] == ["c.png"]


def pareto_point(series: str, method: str, seconds: float, mrse: float, front: bool) -> dict:
    return {"series": series, "method": method, "seconds_per_frame": seconds,
            "seconds_spread": [0.9 * seconds, 1.1 * seconds], "mrse": mrse,
            "front_mrse": front}


def test_pareto_has_a_y_label_a_black_front_and_one_hue_per_family(
        tmp_path: Path, figures: list[Figure], monkeypatch: pytest.MonkeyPatch) -> None:
    # Values inside one decade: matplotlib labels minor ticks (4x10^-1), wide enough to
    # push a fixed margin's y label out of the figure.
    points = [pareto_point("paper's PT", "pt", 0.01, 0.5, False),
              pareto_point("paper's PT", "pt", 0.02, 0.25, False),
              pareto_point("PT (throughput RR)", "pt", 0.008, 0.45, True),
              pareto_point("PT (throughput RR)", "pt", 0.016, 0.22, True),
              pareto_point("NIRC", "nirc", 0.015, 0.2, True),
              pareto_point("grid-cache", "grid-cache", 0.03, 0.3, False)]
    assert_png(plot_pareto(points, "mrse", "MRSE", tmp_path / "p.png", "pareto"))
    (ax,) = figures[0].axes
    assert_y_label_inside(figures[0], "MRSE")
    legend = {label: to_hex((handle[0] if isinstance(handle, tuple) else handle).get_color())
              for handle, label in zip(*ax.get_legend_handles_labels(), strict=True)}
    assert legend.pop("Pareto front") == FRONT_COLOUR
    series = legend
    assert len(set(series.values())) == 4 and FRONT_COLOUR not in series.values()
    assert series["NIRC"] == FAMILY_COLOURS["nirc"]
    assert FAMILY_COLOURS["pt"] in {series["paper's PT"], series["PT (throughput RR)"]}
    # Planted: the fixed margins without fitting leave the y label outside the figure.
    monkeypatch.setattr(plots, "fit_margins", lambda figure: None)
    assert_png(plot_pareto(points, "mrse", "MRSE", tmp_path / "q.png", "pareto"))
    with pytest.raises(AssertionError):
        assert_y_label_inside(figures[1], "MRSE")


def test_pareto_draws_the_strongest_pt_as_one_wide_grey_series(
        tmp_path: Path, figures: list[Figure]) -> None:
    """Two stretches of the envelope (a gap between them) are one legend entry, drawn
    under the points in the envelope's style; without an envelope there is none."""
    points = [pareto_point("pt (rr_mode throughput)", "pt", 0.01, 0.5, True),
              pareto_point("pt (rr_mode throughput)", "pt", 0.02, 0.25, True),
              pareto_point("pt-power (rr_mode throughput)", "pt-power", 0.04, 0.2, True),
              pareto_point("pt-power (rr_mode throughput)", "pt-power", 0.08, 0.1, True)]
    stretches = [[(0.01, 0.5), (0.02, 0.25)], [(0.04, 0.2), (0.08, 0.1)]]
    assert_png(plot_pareto(points, "mrse", "MRSE", tmp_path / "p.png", "pareto",
                           envelope=stretches))
    (ax,) = figures[0].axes
    labels = ax.get_legend_handles_labels()[1]
    assert labels.count("strongest PT") == 1
    drawn = [line for line in ax.get_lines() if line.get_linewidth() == ENVELOPE_WIDTH]
    assert [list(zip(line.get_xdata(), line.get_ydata(), strict=True)) for line in drawn] \
        == stretches
    assert all(to_hex(line.get_color()) == ENVELOPE_STYLE.colour
               and line.get_zorder() < 1 for line in drawn)
    assert_png(plot_pareto(points, "mrse", "MRSE", tmp_path / "q.png", "pareto"))
    assert "strongest PT" not in figures[1].axes[0].get_legend_handles_labels()[1]
