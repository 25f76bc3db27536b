"""
The PNG plots of ``mlx-tempcomp diagnose`` (matplotlib, imported when they are drawn).

The residual against temperature and against time, before and after the
diagnosed effects, heating and cooling coloured, the two panels of an axis
on one y-scale; the held-out error per step and the error by temperature
(`toolkit.uncertainty`), each beside PX4's cubic clamped at its range, the
reference. Legends lie below the panels, outside them, so no label covers
another (`test/support/plot_checks.py` checks it).
"""

import math
from pathlib import Path

from ..uncertainty import plot_error_by_temperature

PLOTS = ('residual_vs_temperature.png', 'residual_vs_time.png', 'error_per_step.png',
         'error_by_temperature.png')
# Plots draw at most this many bins per axis (every k-th bin beyond).
MAX_PLOT_POINTS = 20000
_TITLES = (('temperature polynomial', 'before_rad_s'), ('diagnosed', 'after_rad_s'))
CUBIC_TEXT = "PX4's cubic, clamped"


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


def _legend_below(figure, plot, markerscale: float = 1.0) -> None:
    """One legend for the figure, below its panels, from one panel's labelled artists."""
    handles, labels = plot.get_legend_handles_labels()
    figure.legend(handles, labels, loc='outside lower center', ncol=min(len(labels), 5),
                  fontsize='small', markerscale=markerscale)


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
    """Draw the residuals against temperature, before and after, an axis on one scale."""
    axes = diagnosis.axes
    figure, grid = pyplot.subplots(len(axes), 2, figsize=(11.0, 3.2 * len(axes) + 0.6),
                                   squeeze=False, sharex=True, sharey='row',
                                   layout='constrained')
    _residual_panels(grid, axes, parts, _TITLES, lambda part: part.temperature_c)
    for plot in grid[-1]:
        plot.set_xlabel('temperature (C)')
    _legend_below(figure, grid[0][0], markerscale=3)
    _save(pyplot, figure, path)


def _residual_vs_time(pyplot, path: Path, diagnosis, parts: list) -> None:
    """Draw the residuals against the time since the start, the test set shaded."""
    axes = diagnosis.axes
    figure, grid = pyplot.subplots(len(axes), 2, figsize=(13.0, 3.0 * len(axes) + 0.6),
                                   squeeze=False, sharex=True, sharey='row',
                                   layout='constrained')
    start_s = diagnosis.held_out.time_s[0]
    if diagnosis.test is not None:
        for plot in grid.flat:
            plot.axvspan(diagnosis.test.time_s[0] - start_s,
                         diagnosis.test.time_s[-1] - start_s, color='0.9', zorder=0,
                         label='test set')
    _residual_panels(grid, axes, parts, _TITLES, lambda part: part.time_s - start_s)
    for plot in grid[-1]:
        plot.set_xlabel('time since start (s)')
    _legend_below(figure, grid[0][0], markerscale=3)
    _save(pyplot, figure, path)


def _error_per_step(pyplot, path: Path, diagnosis) -> None:
    """
    Draw each axis's held-out RMS after each step, beside the clamped cubic's.

    One panel per axis on one scale, the steps named on the x-axis; the
    cubic's held-out RMS (deciding scheme) dashed across; with a test part,
    the written model's and the cubic's RMS there.
    """
    axes = diagnosis.per_axis
    figure, grid = pyplot.subplots(1, len(axes), figsize=(4.2 * len(axes), 4.8), squeeze=False,
                                   sharey=True, layout='constrained')
    scheme = diagnosis.settings.validation
    test = diagnosis.comparison.get('test')
    for k, (plot, axis) in enumerate(zip(grid[0], axes)):
        values = [axis.steps[0].before.rms_rad_s] + [s.after.rms_rad_s for s in axis.steps]
        # One word a line: the names stand level, side by side, none over another.
        labels = ['none'] + [s.effect.replace('_', '\n') for s in axis.steps]
        last = len(values) - 1
        plot.semilogy(range(len(values)), values, marker='o', color='C0',
                      label=f'held-out ({scheme.replace("_", "-")})')
        cubic = diagnosis.comparison[scheme]['px4_cubic'][k].rms_rad_s
        plot.axhline(cubic, color='0.4', ls='--', label=f'{CUBIC_TEXT}, held-out')
        if test is not None:
            plot.semilogy([last], [test['diagnosed'][k].rms_rad_s], 'x', color='C3', ms=9,
                          label='written model, test part')
            plot.axhline(test['px4_cubic'][k].rms_rad_s, color='C3', ls=':',
                         label=f'{CUBIC_TEXT}, test part')
        plot.set_xticks(range(len(values)), labels, fontsize='small')
        plot.set_title(f'axis {axis.axis}')
        plot.grid(True, which='both', alpha=0.3)
    grid[0][0].set_ylabel('RMS of the residual (rad/s)')
    figure.suptitle('Held-out error per step')
    _legend_below(figure, grid[0][0])
    _save(pyplot, figure, path)


def _save(pyplot, figure, path: Path) -> None:
    try:
        figure.savefig(path, dpi=100)
    finally:
        pyplot.close(figure)
