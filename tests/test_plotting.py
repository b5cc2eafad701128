"""The speed-against-error chart: labels never overlap, whatever the points."""

import numpy as np
import pytest
from matplotlib.text import Text

from benchmark.scoring import plotting
from benchmark.scoring.plotting import Point


@pytest.mark.parametrize("n", [1, 5, 40])
def test_spread_keeps_gap_range_and_order(n):
    rng = np.random.default_rng(n)
    wanted = sorted(rng.uniform(0.4, 0.45, n).tolist())  # crowded: all within 0.05
    gap = 1.0 / (n + 1)
    pos = plotting.spread(wanted, gap, 0.0, 1.0)
    assert all(b - a >= gap - 1e-12 for a, b in zip(pos, pos[1:]))
    assert 0.0 <= min(pos) and max(pos) <= 1.0


def test_spread_leaves_room_alone():
    wanted = [0.1, 0.5, 0.9]
    assert plotting.spread(wanted, 0.05, 0.0, 1.0) == wanted


def _boxes(fig):
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    ax = fig.axes[0]
    # the text's own box: an Annotation's extent would include its leader line
    return {t.get_text(): Text.get_window_extent(t, renderer) for t in ax.texts}


def test_chart_labels_do_not_overlap():
    # 20 models with almost equal errors (the usual collapsed table) and close references
    points = [
        Point(
            10.0 ** (1 + i / 10),
            133.0 + 0.01 * i,
            f"model-{i}",
            ci=(80.0, 180.0),
            hollow=i % 2 == 0,
        )
        for i in range(20)
    ]
    refs = {"train-mean": 133.0, "class-mean": 181.0, "nearest-scale": 166.0, "class-nn": 162.0}
    fig = plotting.speed_vs_error(points, refs, simulator=(30.0, 16.8), title="t")
    boxes = _boxes(fig)
    assert len(boxes) == 20 + 4 + 1  # every label drawn once
    items = list(boxes.values())
    for i, a in enumerate(items):
        for b in items[i + 1 :]:
            assert not a.overlaps(b)
    assert plotting.png(fig)[:8] == b"\x89PNG\r\n\x1a\n"


def test_chart_grows_for_many_labels():
    few = plotting.speed_vs_error([Point(1.0, 1.0, "a")])
    many = plotting.speed_vs_error([Point(1.0 + i, 50.0, f"m{i}") for i in range(60)])
    assert many.get_figheight() > few.get_figheight()
    boxes = list(_boxes(many).values())
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])
