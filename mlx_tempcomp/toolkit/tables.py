"""
The console tables and lines the commands print: what a fit chose and what it derived.

`format_order_table` (``fit``: every order's held-out RMS per axis, the chosen one
marked), `format_btc_table` (``fit --model linear_btc`` and ``adis-bias``: the ADIS16130
note's Table 6), `format_stage_table` (``fit --model chain``: the error left after
each stage) and `bounds_lines` (``fit`` and ``diagnose``: the bias tracking bounds the
record gives, `core.standstill.tracking_bounds`). The core computes; these only say it.
"""

import math

from ..core.effects import EffectModel, LinearBtc


def format_order_table(selections) -> str:
    """Return a table of every order's held-out RMS per axis, the chosen order marked."""
    header = ('axis', 'order', 'mean held-out RMS (rad/s)', '(deg/s)', 'standard error (rad/s)',
              'chosen')
    rows = []
    for selection in selections:
        for score in selection.scores:
            if math.isfinite(score.mean_rms_rad_s):
                mean_text = f'{score.mean_rms_rad_s:.3e}'
                degrees_text = f'{math.degrees(score.mean_rms_rad_s):.4g}'
                error_text = f'{score.standard_error_rad_s:.3e}'
            else:
                mean_text = 'unsupported'
                degrees_text = error_text = '-'
            rows.append((selection.axis, str(score.order), mean_text, degrees_text, error_text,
                         '*' if score.order == selection.order else ''))
    widths = [max(len(row[i]) for row in (header, *rows)) for i in range(len(header))]
    lines = ['  '.join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip()
             for row in (header, *rows)]
    lines.extend(f'{selection.axis}: {selection.rule}' for selection in selections)
    return '\n'.join(lines)


def format_btc_table(model: EffectModel, axes, step_c: float, rows_each_side: int = 6) -> str:
    """
    Return the ADIS16130 note's Table 6 for a linear_btc model: (TEMP - T3) and (TEMP - T3) x BTC.

    Rows run from +rows_each_side to -rows_each_side steps of ``step_c``; the
    columns after the first give the correction per axis in rad/s and, beside
    it, in deg/s as the note prints it.
    """
    def text(value: float, digits: int) -> str:
        return '0' if value == 0.0 else f'{value:+.{digits}g}'

    header = ('TEMP - T3 (C)', *(f'{axis} ({unit})' for axis in axes
                                 for unit in ('rad/s', 'deg/s')))
    rows = []
    slopes = LinearBtc.of(model).btc_rad_s_per_c
    for k in range(rows_each_side, -rows_each_side - 1, -1):
        offset_c = k * step_c
        rows.append((text(offset_c, 6), *(text(value, 4) for btc in slopes
                                          for value in (offset_c * btc,
                                                        math.degrees(offset_c * btc)))))
    widths = [max(len(row[i]) for row in (header, *rows)) for i in range(len(header))]
    return '\n'.join('  '.join(cell.rjust(width) for cell, width in zip(row, widths))
                     for row in (header, *rows))


def format_stage_table(rows) -> str:
    """Render `StageError` rows as text, in % of full scale and in rad/s."""
    lines = [f'{"stage":<13}{"axis":<5}{"mean %FS":>10}{"1 sigma":>10}{"peak":>10}'
             f'{"mean rad/s":>13}{"1 sigma":>11}{"peak":>11}{"RMS":>11}']
    for row in rows:
        lines.append(f'{row.stage:<13}{row.axis:<5}{row.mean_percent_fs:>10.4f}'
                     f'{row.sigma_percent_fs:>10.4f}{row.peak_percent_fs:>10.4f}'
                     f'{row.mean_rad_s:>13.3e}{row.sigma_rad_s:>11.3e}'
                     f'{row.peak_rad_s:>11.3e}{row.rms_rad_s:>11.3e}')
    return '\n'.join(lines)


def bounds_lines(values: dict, axes: tuple, notes: dict) -> list:
    """Say what was derived, for the console."""
    def per_axis(key):
        return ', '.join(f'{a} {v:.3g}' for a, v in zip(axes, values[key]))

    lines = [
        f'bias tracking (bias_tracking.*, on): windows of {values["window_s"]:g} s; '
        f'noise of a sample {per_axis("rate_noise_rad_s")} rad/s (spread bound '
        f'{values["noise_multiple"]:.3g} x); random walk {per_axis("random_walk_rad_s_rt_s")} '
        'rad/s/sqrt(s)',
        f'  offset without tracking (window means, RMS) {per_axis("initial_std_rad_s")} rad/s; '
        f'a constant turn below {values["max_mean_rate_rad_s"]:.4g} rad/s '
        f'({math.degrees(values["max_mean_rate_rad_s"]):.3g} deg/s) is rest to the tracker; '
        f'temperature rate bound {values["max_temperature_rate_c_s"]:.3g} C/s',
    ]
    if 'max_tilt_rate_rad_s' in values:
        lines.append(f'  accelerometer: spread bound {values["max_acceleration_spread_m_s2"]:.3g} '
                     f'm/s^2, tilt rate bound {values["max_tilt_rate_rad_s"]:.3g} rad/s')
    lines += [f'  {key}: {note}' for key, note in notes.items()]
    return lines
