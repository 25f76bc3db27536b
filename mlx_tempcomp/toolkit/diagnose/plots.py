"""
The PNG plots of ``mlx-tempcomp diagnose`` (matplotlib, imported when they are drawn).

The residual against temperature and against time, before and after the
diagnosed effects, heating and cooling coloured; the held-out error per
step; the error by temperature (`toolkit.uncertainty`).
"""

import math
from pathlib import Path

from ..uncertainty import plot_error_by_temperature

PLOTS = ('residual_vs_temperature.png', 'residual_vs_time.png', 'error_per_step.png',
         'error_by_temperature.png')
# Plots draw at most this many bins per axis (every k-th bin beyond).
MAX_PLOT_POINTS = 20000
_TITLES = (('temperature polynomial', 'before_rad_s'), ('diagnosed', 'after_rad_s'))


def _every(count: int) -> slice:
    return slice(None, None, max(1, math.ceil(count / MAX_PLOT_POINTS)))


_BRANCHES = ((True, 'tab:red', 'heating'), (False, 'tab:blue', 'cooling'))


def _residual_panels(grid, axes, parts, titles, x_of) -> None:
    """Scatter each part's residuals against ``x_of(part)``, heating and cooling coloured."""
    for row, name in enumerate(axes):
        for column, (title, values) in enumerate(titles):
            plot = grid[row][column]
            for part, label, marker in parts:
                pick = _every(len(part.time_s))
                x = x_of(part)[pick]
                for heating, colour, branch in _BRANCHES:
                    mask = part.heating[pick] == heating
                    plot.scatter(x[mask], getattr(part, values)[pick, row][mask], s=3, c=colour,
                                 marker=marker, label=f'{branch}, {label}')
            plot.set_title(f'{name}: {title}')
            plot.set_ylabel('residual (rad/s)')
            plot.grid(True, alpha=0.3)
        grid[row][0].legend(markerscale=3, fontsize='small')


def write_plots(out: Path, diagnosis) -> None:
    """Draw the plots of `PLOTS` into the folder ``out``."""
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib import pyplot

    parts = [(diagnosis.held_out, 'held-out folds', 'o')]
    if diagnosis.test is not None:
        parts.append((diagnosis.test, 'test set', 'x'))
    _residual_vs_temperature(pyplot, out / PLOTS[0], diagnosis, parts)
    _residual_vs_time(pyplot, out / PLOTS[1], diagnosis, parts)
    _error_per_step(pyplot, out / PLOTS[2], diagnosis)
    plot_error_by_temperature(out / PLOTS[3], diagnosis, _save)


def _residual_vs_temperature(pyplot, path: Path, diagnosis, parts: list) -> None:
    axes = diagnosis.axes
    figure, grid = pyplot.subplots(len(axes), 2, figsize=(11.0, 3.2 * len(axes)),
                                   squeeze=False, sharex=True)
    _residual_panels(grid, axes, parts, _TITLES, lambda part: part.temperature_c)
    for plot in grid[-1]:
        plot.set_xlabel('temperature (C)')
    _save(pyplot, figure, path)


def _residual_vs_time(pyplot, path: Path, diagnosis, parts: list) -> None:
    """Draw the residuals against the time since the start, the test set shaded."""
    axes = diagnosis.axes
    figure, grid = pyplot.subplots(len(axes), 2, figsize=(13.0, 3.0 * len(axes)),
                                   squeeze=False, sharex=True, sharey='row')
    start_s = diagnosis.held_out.time_s[0]
    if diagnosis.test is not None:
        for plot in grid.flat:
            plot.axvspan(diagnosis.test.time_s[0] - start_s,
                         diagnosis.test.time_s[-1] - start_s, color='0.9', zorder=0,
                         label='test set')
    _residual_panels(grid, axes, parts, _TITLES, lambda part: part.time_s - start_s)
    for plot in grid[-1]:
        plot.set_xlabel('time since start (s)')
    _save(pyplot, figure, path)


def _error_per_step(pyplot, path: Path, diagnosis) -> None:
    """Draw each axis's held-out RMS after each step, the step's effect beside its point."""
    from matplotlib.ticker import MaxNLocator

    figure, plot = pyplot.subplots(figsize=(8.0, 4.5))
    for axis in diagnosis.per_axis:
        values = [axis.steps[0].before.rms_rad_s] + [s.after.rms_rad_s for s in axis.steps]
        labels = ['none'] + [s.effect for s in axis.steps]
        plot.semilogy(range(len(values)), values, marker='o', label=f'axis {axis.axis}')
        for index, label in enumerate(labels):
            plot.annotate(label, (index, values[index]), fontsize=7, rotation=20,
                          textcoords='offset points', xytext=(3, 3))
    plot.set_xlabel('step')
    plot.xaxis.set_major_locator(MaxNLocator(integer=True))
    plot.set_ylabel('held-out RMS (rad/s)')
    plot.set_title('Held-out error per step')
    plot.grid(True, which='both', alpha=0.3)
    plot.legend()
    _save(pyplot, figure, path)


def _save(pyplot, figure, path: Path) -> None:
    try:
        figure.tight_layout()
        figure.savefig(path, dpi=100)
    finally:
        pyplot.close(figure)
