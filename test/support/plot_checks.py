"""
Whether a matplotlib figure's labels overlap: titles, axis and tick labels, legends.

`overlapping_labels` draws the figure and gives every pair of visible texts
(a legend counts as one box, its entries inside it) whose boxes on the
canvas overlap. `drawn_figures` records it, and the figure, for each figure a command saves,
by wrapping ``Figure.savefig`` (the command runs as a user runs it).
"""

import contextlib
import itertools
from pathlib import Path

from matplotlib.figure import Figure
from matplotlib.text import Text

# Boxes that touch within this many pixels are not counted as overlapping.
TOLERANCE_PX = 0.5


def _tick_labels(figure) -> tuple:
    """Give (the tick labels drawn: their ticks lie in view, every tick label)."""
    drawn, every = [], []
    for plot in figure.axes:
        for axis in (plot.xaxis, plot.yaxis):
            low, high = sorted(axis.get_view_interval())
            span = high - low
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                labels = [tick.label1, tick.label2]
                every += labels
                if low - 1e-9 * span <= tick.get_loc() <= high + 1e-9 * span:
                    drawn += [label for label in labels if label.get_visible()]
    return drawn, every


def _boxes(figure) -> list:
    """Give (what, box) of every label drawn: texts, and each legend as a whole."""
    renderer = figure.canvas.get_renderer()
    legends = list(figure.legends) + [plot.get_legend() for plot in figure.axes
                                      if plot.get_legend() is not None]
    drawn, every = _tick_labels(figure)
    entries = [text for legend in legends for text in [*legend.get_texts(), legend.get_title()]]
    skipped = {id(text) for text in entries}
    skipped |= {id(text) for text in every}
    boxes = [(f'legend {k}', legend.get_window_extent(renderer))
             for k, legend in enumerate(legends)]
    texts = drawn + [text for text in figure.findobj(Text) if id(text) not in skipped]
    for text in texts:
        if text.get_visible() and text.get_text().strip():
            boxes.append((repr(text.get_text()), text.get_window_extent(renderer)))
    return boxes


def overlapping_labels(figure) -> list:
    """Give the pairs of labels whose boxes overlap on the drawn figure."""
    figure.canvas.draw()
    found = []
    for (a, box_a), (b, box_b) in itertools.combinations(_boxes(figure), 2):
        if box_a.x0 + TOLERANCE_PX < box_b.x1 and box_b.x0 + TOLERANCE_PX < box_a.x1 and \
                box_a.y0 + TOLERANCE_PX < box_b.y1 and box_b.y0 + TOLERANCE_PX < box_a.y1:
            found.append((a, b))
    return found


@contextlib.contextmanager
def drawn_figures(monkeypatch):
    """
    Record {file name: (overlapping labels, the figure)} of every figure saved in the block.

    A file written through a staging name (``.allan.png.1234.partial``) is
    recorded under its own name.
    """
    saved = {}
    original = Figure.savefig

    def savefig(figure, path, *args, **kwargs):
        name = Path(str(path)).name
        if name.startswith('.') and name.endswith('.partial'):
            name = name[1:].rsplit('.', 2)[0]
        saved[name] = (overlapping_labels(figure), figure)
        return original(figure, path, *args, **kwargs)

    monkeypatch.setattr(Figure, 'savefig', savefig)
    yield saved
