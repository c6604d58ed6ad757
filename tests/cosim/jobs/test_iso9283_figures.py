"""The ISO 9283 figures draw each 1 ms series through its extremes per column
(cosim/jobs/iso9283_figures.envelope): every peak is kept and the drawn picture is the
picture of the whole line."""
from __future__ import annotations

import numpy as np
import pytest

from cosim.jobs.iso9283_figures import ENVELOPE_COLUMNS, envelope


def noisy_series(n: int = 12600, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    y = 10 * np.sin(2 * np.pi * 0.4 * t) + rng.normal(0.0, 1.0, n)
    y[4321] = 40.0  # a single-sample spike
    y[9876] = -35.0
    return t, y


def test_envelope_keeps_every_column_extreme_in_order():
    t, y = noisy_series()
    x, v = envelope(t, y)
    assert x.size <= 2 * ENVELOPE_COLUMNS + 2 and x.size < t.size / 3
    assert np.all(np.diff(x) > 0)  # original order, no duplicates
    assert v.max() == 40.0 and v.min() == -35.0
    assert x[0] == t[0] and x[-1] == t[-1]
    column = np.minimum(((t - t[0]) * (ENVELOPE_COLUMNS / (t[-1] - t[0]))).astype(int), ENVELOPE_COLUMNS - 1)
    kept = np.minimum(((x - t[0]) * (ENVELOPE_COLUMNS / (t[-1] - t[0]))).astype(int), ENVELOPE_COLUMNS - 1)
    for c in range(0, ENVELOPE_COLUMNS, 37):
        assert v[kept == c].max() == y[column == c].max() and v[kept == c].min() == y[column == c].min()


@pytest.mark.parametrize("x, y", [(np.arange(100.0), np.ones(100)),                       # few points
                                  (np.r_[np.arange(5000.0), 3.0], np.ones(5001)),          # x not sorted
                                  (np.arange(5000.0), np.r_[np.ones(4999), np.nan]),
                                  (np.arange(4000.0), np.ones(4000))])      # a gap
def test_envelope_leaves_short_unsorted_or_gapped_lines_whole(x, y):
    ex, ey = envelope(x, y)
    assert ex.size == x.size and np.array_equal(ey, y, equal_nan=True)


def test_log_x_columns_keep_the_spectrum_peaks():
    f = np.linspace(0.08, 500.0, 20000)
    a = 1.0 / f
    a[15000] = 50.0
    x, v = envelope(f, a, log_x=True)
    assert x.size < f.size and v.max() == 50.0 and x[0] == f[0] and x[-1] == f[-1]


def render(x: np.ndarray, y: np.ndarray, log: bool = False) -> np.ndarray:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 4.5), dpi=110)
    canvas = FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.plot(x, y, lw=0.8, color="tab:red")
    if log:
        ax.set_yscale("log")
    ax.set_xlim(0.0, 12.6)
    ax.set_axis_off()
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].astype(int)


@pytest.mark.parametrize("log", [False, True])
def test_the_drawn_picture_is_the_whole_lines_picture(log):
    t, y = noisy_series()
    if log:
        y = np.abs(y) + 1e-3
    whole, drawn = render(t, y, log), render(*envelope(t, y), log)
    inked_whole, inked_drawn = (whole.sum(axis=2) < 700), (drawn.sum(axis=2) < 700)
    assert inked_whole.sum() > 10000
    differ = np.abs(whole - drawn).max(axis=2) > 64  # more than a quarter of full scale in a channel
    # measured: 98 / 339 differing pixels and 70 / 278 inked in one picture only, of 16 773 / 38 103 inked
    assert differ.sum() < 0.015 * inked_whole.sum()
    assert np.logical_xor(inked_whole, inked_drawn).sum() < 0.01 * inked_whole.sum()


FORKED = """
import sys, types
from pathlib import Path
import numpy as np
from cosim.jobs.iso9283_figures import write_figures

rng = np.random.default_rng(2)
n = 12600
t = np.arange(n) * 1e-3
def result(scale):
    err = scale * (1 + np.abs(rng.normal(0, 1, n)))
    hz = np.linspace(0, 500, 6301)
    return types.SimpleNamespace(t=t, lag=scale * rng.normal(0, 1, (n, 6)), arc_length=np.linspace(0, 8, n),
                                 tcp_error=err, path_error=2 * err, spectrum_hz=hz, spectrum_m=scale / (1 + hz),
                                 residual_t=np.arange(190) * 1e-3, residual_error=scale * np.exp(-np.arange(190) / 40),
                                 residual={"peak_mm": 1.0, "settling_time_s": 0.06, "static_offset_mm": 0.001,
                                           "band_mm": 0.02})
results = {"standard": result(1e-2), "model_based": result(1e-5)}
path = types.SimpleNamespace(segments=[types.SimpleNamespace(arc_start=a) for a in (0.0, 2.0, 5.0)])
out = Path(sys.argv[1])
for name in ("one", "two", "three", "four", "five"):
    (out / name).mkdir()

# drawn by the figure process (forked before anything heavy, as `cosim run` does): this process
# never imports matplotlib, and the figure process has ended when the files are there
import multiprocessing, os, signal
from cosim.results import figure_process
helper = figure_process.start("cosim.jobs.iso9283_figures:warm_up")
assert helper is not None and figure_process.current() is helper
three = write_figures(out / "three", results, path)
assert "matplotlib" not in sys.modules
assert figure_process.current() is None and not multiprocessing.active_children()

# a figure process that died: the job draws the figures itself
helper = figure_process.start("cosim.jobs.iso9283_figures:warm_up")
os.kill(helper.pid, signal.SIGKILL)
four = write_figures(out / "four", results, path)
assert figure_process.current() is None and not multiprocessing.active_children()

one = write_figures(out / "one", results, path, processes=1)
two = write_figures(out / "two", results, path)
# the four figures' axes made and drawn once by the warm-up, then taken by the figures
from cosim.jobs import iso9283_figures
iso9283_figures.warm_up()
assert sorted(iso9283_figures._PREPARED) == ["lag", "path_error", "tcp_error", "vibration"]
five = write_figures(out / "five", results, path, processes=1)
assert not iso9283_figures._PREPARED
assert [p.name for p in one] == [p.name for p in two] == [p.name for p in three] == [p.name for p in four] == [
    p.name for p in five]
"""


def test_figures_drawn_in_two_processes_are_the_same_files(tmp_path):
    """The vibration figure drawn by the forked process, and all four drawn by the figure process
    (cosim/results/figure_process.py, also after it died: then by the job itself), and those drawn
    on the axes the warm-up prepared, are byte for byte the ones drawn in the job's own process."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    script = tmp_path / "forked.py"
    script.write_text(FORKED)
    done = subprocess.run([sys.executable, str(script), str(tmp_path)], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(root), "MPLBACKEND": "Agg"})
    assert done.returncode == 0, done.stderr
    names = sorted(p.name for p in (tmp_path / "one").iterdir())
    assert names == ["figure2a_lag_errors.png", "figure2b_tcp_error.png", "tcp_error_vs_desired_path.png",
                     "vibration.png"]
    for name in names:
        for other in ("two", "three", "four", "five"):
            assert (tmp_path / "one" / name).read_bytes() == (tmp_path / other / name).read_bytes(), (other, name)
