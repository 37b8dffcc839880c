"""Plots a reader can read: every PNG legend lies outside every plot area of its figure (no data
hidden under it), every PNG goes through the one saving path (``figures.save_figure``), and the
Rerun phase portraits have labelled axes and both traces visible (the measured one wide, under
the model's narrow line, as in the time series)."""

import contextlib
import io
import re
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest
import rerun as rr

import pendsim_bridge.report.plots as plots
from pendsim_bridge.cli import main
from pendsim_bridge.report import figures, sweep_plots
from pendsim_bridge.report.allan_report import TERM_UNITS, analyse
from pendsim_bridge.report.rerun_view import PHASE_DRAW_ORDER, SERIES_STYLE
from pendsim_bridge.run.validate import validate
from pendsim_mj.estimation.comparison import compare_planar_spatial
from pendsim_mj.rig.model import Variant
from pendsim_mj.rig.params import DEFAULT_PARAMS


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    folder = tmp_path_factory.mktemp("legible")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["record", "-o", str(folder / "run.mcap"), "--duration-s", "6", "--hold-s", "1"]) == 0
        assert main(["record", "--static", "-o", str(folder / "static.mcap"), "--duration-s", "8"]) == 0
        assert main(["view", str(folder / "run.mcap"), "--save", str(folder / "run.rrd")]) == 0
    return folder


@pytest.fixture(scope="module")
def validated(recordings):
    """The run's validation (it draws nothing: the figures are drawn from it by each test, through
    its own save_figure), made once for the two tests that draw them."""
    return validate(recordings / "run.mcap", damping="recorded")


def _overlaps(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


def _check_legends(figure) -> int:
    figure.canvas.draw()
    renderer = figure.canvas.get_renderer()
    areas = [ax.get_window_extent(renderer) for ax in figure.axes]
    legends = [ax.get_legend() for ax in figure.axes if ax.get_legend() is not None] + list(figure.legends)
    for legend in legends:
        box = legend.get_window_extent(renderer)
        assert not any(_overlaps(box, area) for area in areas), f"a legend covers a plot: {figure.axes[0].get_title()}"
    return len(legends)


def test_every_png_legend_lies_outside_the_plot_areas(recordings, validated, tmp_path, monkeypatch):
    checked = []
    original = figures.save_figure

    def check_then_save(figure, path, **kwargs):
        checked.append((path.name, _check_legends(figure)))
        return original(figure, path, **kwargs)

    monkeypatch.setattr(figures, "save_figure", check_then_save)
    plots.validation_figures(validated, tmp_path / "validation")
    comparison = compare_planar_spatial(
        DEFAULT_PARAMS.with_overrides(plane_offset_m=0.05), (0.5, 0.0), 2.0, variant=Variant(tilt=True)
    )
    plots.comparison_figures(comparison, tmp_path / "compare")
    allan = analyse(recordings / "static.mcap")
    node_axes = [a for a in allan.axes if a.node == "m1" and a.sensor == "gyro"]
    plots.allan_plot(
        [a.curve for a in node_axes],
        [a.terms for a in node_axes],
        [a.axis for a in node_axes],
        title="m1 gyroscope",
        unit="rad/s",
        term_units=TERM_UNITS["gyro"],
        path=tmp_path / "allan.png",
    )
    x = np.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0]])
    sweep_plots._scatter(
        tmp_path / "scatter.png", x, np.array([0.5, np.nan, 0.7]), ("a", "b"), "f", "diverged", (False, True)
    )
    assert len(checked) == 7 + 3 + 1 + 1
    assert sum(n for _, n in checked) >= 11  # the figures have legends: 6 validation, 4 compare, Allan, sweep
    assert matplotlib.get_backend().lower() == "agg"


def test_save_figure_refuses_a_legend_over_the_data_and_writes_nothing(tmp_path):
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1], label="over the data")
    ax.legend(loc="center")
    with pytest.raises(ValueError, match="a legend covers the plot"):
        figures.save_figure(fig, tmp_path / "bad.png")
    assert not list(tmp_path.iterdir())  # no file, no temporary left behind
    assert not plt.fignum_exists(fig.number)  # closed all the same


def test_every_png_is_written_by_save_figure_alone():
    bridge = Path(figures.__file__).parents[1]
    savers = sorted(
        str(p.relative_to(bridge)) for p in bridge.rglob("*.py") if re.search(r"\.savefig\(", p.read_text())
    )
    assert savers == ["report/figures.py"]


def test_whole_run_figures_show_the_differences_under_the_overlay(validated, tmp_path, monkeypatch):
    saved = {}
    original = figures.save_figure

    def keep_then_save(figure, path, **kwargs):
        saved[path.name] = [(a.get_ylabel(), [line.get_ydata() for line in a.get_lines()]) for a in figure.axes]
        return original(figure, path, **kwargs)

    monkeypatch.setattr(figures, "save_figure", keep_then_save)
    report = validated
    plots.validation_figures(report, tmp_path / "validation")
    whole = {name: axes for name, axes in saved.items() if "whole" in name}
    assert set(whole) == {"fig12_phi1_whole.png", "fig15_omega2_whole.png"}
    for name, quantity in (("fig12_phi1_whole.png", "phi1"), ("fig15_omega2_whole.png", "omega2")):
        (_, upper), (label, lines) = whole[name]
        assert label.startswith("computed - measured")
        measured = report.run.series(quantity)[1]
        np.testing.assert_array_equal(upper[0], measured)  # no gaps here: the series unbroken
        # MuJoCo's computed line less the measured one (the figure takes it in float32)
        np.testing.assert_allclose(lines[0], upper[1] - upper[0], rtol=1e-6, atol=1e-9)
        assert np.max(np.abs(lines[0])) < 0.05 * np.max(np.abs(measured))  # small against the swing
    assert all(len(axes) == 1 for name, axes in saved.items() if "whole" not in name and "fig14" not in name)


def _static_rows(rrd) -> dict[str, list[dict]]:
    rows: dict[str, list[dict]] = {}
    for chunk in rr.chunk.RrdReader(str(rrd)).stream():
        if chunk.is_static:
            rows.setdefault(str(chunk.entity_path), []).extend(chunk.to_record_batch().to_pylist())
    return rows


def _column(rows: list[dict], suffix: str):
    return next(value for row in rows for key, value in row.items() if key.endswith(suffix) and value is not None)


def test_phase_portraits_have_labelled_axes_and_both_traces_visible(recordings):
    rows = _static_rows(recordings / "run.rrd")
    for k in (1, 2):
        labels = _column(rows[f"/phase/m{k}/axes/labels"], ":labels")
        assert f"phi{k} (rad)" in labels and f"omega{k} (rad/s)" in labels
        ticks = [float(t) for t in labels if t.replace(".", "").replace("-", "").isdigit()]
        assert len(ticks) >= 4 and 0.0 in ticks  # numbered ticks on both axes
        measured = _column(rows[f"/phase/m{k}/measured"], ":radii")[0]
        model = _column(rows[f"/phase/m{k}/model"], ":radii")[0]
        assert measured >= 2 * model  # the measured band shows on both sides of the model's line
        strip = np.asarray(_column(rows[f"/phase/m{k}/measured"], ":strips")[0])
        assert strip.shape[1] == 2 and len(strip) > 400  # every measured sample after the start (80 Hz)
    assert PHASE_DRAW_ORDER["model"] > PHASE_DRAW_ORDER["measured"]
    # the time series: the same band-and-line styling, in distinct colours
    measured_style, model_style = SERIES_STYLE["measured"], SERIES_STYLE["model"]
    assert measured_style[2] >= 2 * model_style[2] and measured_style[1] != model_style[1]
    width = _column(rows["/plots/phi1/measured"], ":widths")
    assert width == [measured_style[2]]
