"""
What ``diagnose`` and ``fit`` say about temperatures beyond the fit, and the error per temperature.

Beyond the temperatures a model was fitted on, the node clamps the
temperature at the edge of that range (docs/ros.md). These functions turn
the diagnosis's `OutsideFittedRange` (how much of the test part and of each
forward held-out block lies outside the range the model predicting it was
fitted on) and `ErrorByTemperature` (the held-out error of the written model
per temperature bin) into report.json sections, report.md lines, console
lines, a plot and the ``model_error.*`` node parameters.
"""

import math

import numpy as np

from ..core.node_models import bias_rms_rad_s
from ..parameters.files import model_error_parameters

OUTSIDE_MEANING = ('rows whose temperature (T_eff with a thermal lag) lies outside the range '
                   'the model predicting them was fitted on: the node clamps the temperature at '
                   'the edge there, so the correction holds the edge value')
ERROR_MEANING = ('per temperature bin, the RMS of the held-out residual of the model written '
                 '(corrected - truth, averaged over bins of average_s seconds, as the held-out '
                 'RMS), rad/s, under the deciding scheme and the one beside (one of them '
                 'forward: later in time than the fit); the table params.yaml carries as '
                 'model_error.* is per bin the larger of the two with the white noise share '
                 'taken out (noise^2 / samples per averaged value): a bias error, which the '
                 'node adds to the white noise of a sample squared (model_error.rate_noise_rad_s) '
                 'in the Imu covariance')
NORMALISED_MEANING = ('the written model on the test part, as written: per axis the RMS of '
                      "each sample's error over the standard deviation params.yaml publishes "
                      "for it (sqrt(noise^2 + model_error(T)^2)), and of each window's mean "
                      'error over the standard deviation of such a mean (the model error '
                      "whole, the noise over the window's samples); 1 when the covariance "
                      'tells the truth, above 1 when it is too confident')


def _number(value):
    return float(value) if math.isfinite(value) else None


def _part(part, axes) -> dict:
    return {'rows': part.rows, 'range_c': [part.low_c, part.high_c],
            'fraction': dict(zip(axes, part.fraction)),
            'furthest_c': dict(zip(axes, part.furthest_c))}


def _held_blocks(blocks, axes) -> dict:
    """Give the held-out blocks' parts and their share outside, over all of them."""
    parts = [{'block': k, **_part(part, axes)} for k, part in enumerate(blocks)
             if part is not None]
    rows = sum(part['rows'] for part in parts)
    overall = {axis: sum(b['rows'] * b['fraction'][axis] for b in parts) / rows if rows else 0.0
               for axis in axes}
    return {'blocks': parts, 'all': {'rows': rows, 'fraction': overall}}


def outside_range_json(outside, axes, scheme: str) -> dict:
    """
    Return report.json's ``outside_fitted_range``: the test part and each held-out block.

    The forward blocks always (their past's range), and the deciding scheme's
    when it is another (its folds' training range).
    """
    forward = _held_blocks(outside.blocks, axes)
    section = {'meaning': OUTSIDE_MEANING, 'per_axis': outside.per_axis,
               'test': None if outside.test is None else _part(outside.test, axes),
               'forward_scheme': scheme,
               'forward_blocks': forward['blocks'],
               'forward_all': forward['all']}
    if outside.deciding_blocks is not None:
        deciding = _held_blocks(outside.deciding_blocks, axes)
        section.update({'deciding_scheme': outside.deciding,
                        'deciding_blocks': deciding['blocks'], 'deciding_all': deciding['all']})
    return section


def _bins(errors, axes) -> list:
    return [{'low_c': errors.edges_c[k], 'high_c': errors.edges_c[k + 1],
             'temperature_c': errors.temperature_c[k], 'count': errors.count[k],
             'rows': errors.weight[k],
             'rms': {axis: _number(value) for axis, value in zip(axes, errors.rms_rad_s[k])}}
            for k in errors.filled()]


def _table_json(table, axes, edges_c) -> dict:
    """Give the node's table with the temperature bin each of its values comes from."""
    index = [min(int(np.searchsorted(edges_c, t, side='right')) - 1, len(edges_c) - 2)
             for t in table.temperature_c]
    return {'temperature_c': list(table.temperature_c),
            'bins_c': [[edges_c[k], edges_c[k + 1]] for k in index],
            'error_rad_s': {axis: list(values) for axis, values in zip(axes, table.error_rad_s)}}


def error_by_temperature_json(errors, axes) -> dict:
    """Return report.json's ``error_by_temperature``; whether params.yaml has it, and why not."""
    written, not_written = params_model_error(errors, axes)
    return {'meaning': ERROR_MEANING, 'validation': errors.validation,
            'other_validation': errors.other,
            'rows_per_bin': errors.rows_per_bin, 'bins': _bins(errors.held_out, axes),
            'other_bins': _bins(errors.other_held_out, axes),
            'test_bins': None if errors.test is None else _bins(errors.test, axes),
            'test_bias': None if errors.test is None else _bias_bins(errors.test, errors, axes),
            'noise_rad_s': dict(zip(axes, errors.noise_rad_s)),
            'table': None if errors.table is None else
            _table_json(errors.table, axes, errors.held_out.edges_c),
            'in_params_yaml': bool(written), 'not_written': not_written}


def _bias_bins(table, errors, axes) -> list:
    """Give the bias part of a table's filled bins (`model_error.bias_rms_rad_s`)."""
    bias = bias_rms_rad_s(table, errors.noise_rad_s)
    return [{'low_c': table.edges_c[k], 'high_c': table.edges_c[k + 1],
             'temperature_c': table.temperature_c[k],
             'rms': {axis: _number(value) for axis, value in zip(axes, bias[k])}}
            for k in table.filled()]


def normalised_json(normalised, axes) -> dict:
    """Return report.json's ``covariance``: the normalised error on the test part, or None."""
    if normalised is None:
        return None
    return {'meaning': NORMALISED_MEANING, 'window_s': normalised.window_s,
            'samples': normalised.samples, 'windows': normalised.windows,
            'per_sample': dict(zip(axes, normalised.per_sample)),
            'window_means': dict(zip(axes, normalised.window_means))}


def normalised_text(section: dict) -> str:
    """One line: the normalised error per axis, per sample and of the window means."""
    def cells(values):
        return ', '.join(f'{axis} {value:.2f}' for axis, value in values.items())
    return (f'error / published std (RMS; 1 = honest, above 1 = too confident): per sample '
            f'{cells(section["per_sample"])}; {section["window_s"]:g} s means '
            f'{cells(section["window_means"])}')


def _gain_word(gain) -> str:
    if gain is None:
        return '-'
    text = f'{gain:.2f}x'
    return text + (' (the same)' if text == '1.00x' else ' better' if gain > 1.0 else
                   ' (worse)')


def gain_words(gains: dict) -> str:
    """Say each axis's gain over the cubic: '1.94x better', '1.00x (the same)', '0.73x (worse)'."""
    return ', '.join(f'{axis} {_gain_word(gain)}' for axis, gain in gains.items())


def params_model_error(errors, axes) -> tuple:
    """Give (the ``model_error`` node parameters, or {}, and a line saying why not)."""
    if errors.table is None:
        return {}, 'model_error not written: no held-out residual'
    return model_error_parameters(errors.table, axes, errors.noise_rad_s), ''


def percent(fraction: float) -> str:
    """Give a share in per cent; a share near but not at 0 or 1 never rounds to it."""
    if 0.0 < fraction < 0.01:
        return f'{100.0 * fraction:.2g}%'
    if 0.99 < fraction < 1.0:
        return f'{math.floor(1000.0 * fraction) / 10.0:g}%'
    return f'{100.0 * fraction:.0f}%'


def fraction_text(fraction: dict, per_axis: bool) -> str:
    """One share for all axes, or one per axis when their effective temperatures differ."""
    if not per_axis:
        return percent(next(iter(fraction.values())))
    return ', '.join(f'{axis} {percent(value)}' for axis, value in fraction.items())


def _furthest(part: dict) -> float:
    return max(part['furthest_c'].values())


def outside_lines(section: dict) -> list:
    """Give report.md's lines of ``outside_fitted_range``."""
    per_axis = section['per_axis']
    lines = ['## Outside the fitted temperature range', '',
             'Beyond the temperatures a model was fitted on, the compensation node clamps the '
             'temperature at the edge (docs/ros.md): the correction there is the one at the '
             'edge.' + (' Temperatures are per axis (T_eff of its thermal lag).' if per_axis
                        else ''), '']
    test = section['test']
    if test is not None:
        lo, hi = test['range_c']
        lines += [f'- test set: {fraction_text(test["fraction"], per_axis)} of {test["rows"]} '
                  f'rows outside the fitted range {lo:.2f} .. {hi:.2f} C'
                  + (f', at most {_furthest(test):.2f} C beyond' if _furthest(test) else '')]
    overall = section['forward_all']
    lines += [f'- forward held-out blocks: {fraction_text(overall["fraction"], per_axis)} of '
              f'{overall["rows"]} rows outside the range of the blocks before them']
    deciding = section.get('deciding_scheme', '').replace('_', '-')
    if deciding:
        part = section['deciding_all']
        lines += [f'- {deciding} held-out blocks: {fraction_text(part["fraction"], per_axis)} '
                  f'of {part["rows"]} rows outside the range of their fold\'s training blocks']
    lines.append('')
    tables = [('forward_blocks', 'the blocks before')]
    if deciding:
        tables.append(('deciding_blocks', f"the {deciding} fold's training blocks"))
    for key, against in tables:
        rows = [(b['block'], f'{b["range_c"][0]:.2f} .. {b["range_c"][1]:.2f}', b['rows'],
                 fraction_text(b['fraction'], per_axis), f'{_furthest(b):.2f}')
                for b in section[key]]
        lines += [f'| block | range of {against} (C) | rows | outside | furthest beyond (C) |',
                  '|---|---|---|---|---|']
        lines += ['| ' + ' | '.join(str(cell) for cell in row) + ' |' for row in rows] + ['']
    return lines


def _e(value) -> str:
    return '-' if value is None else f'{value:.3e}'


def error_lines(section: dict, axes, covariance) -> list:
    """report.md lines of ``error_by_temperature`` and the normalised error (``covariance``)."""
    scheme = section['validation'].replace('_', '-')
    other = section['other_validation'].replace('_', '-')
    noise = ', '.join(f'{axis} {value:.3e}' for axis, value in section['noise_rad_s'].items())
    lines = ['## Error by temperature (the covariance)', '',
             f'Per temperature bin, the held-out RMS of the model written under {scheme} and '
             f'{other} folds (residuals averaged over bins of {section["rows_per_bin"]:.3g} '
             'samples on average; count: such bins), the larger of the two with the white '
             f'noise share taken out (noise of a sample: {noise} rad/s). It is a bias error, '
             'not white noise: '
             + ('params.yaml carries it as model_error.*, which the node adds to the noise '
                'squared (model_error.rate_noise_rad_s) in the angular velocity covariance.'
                if section['in_params_yaml'] else 'not written into params.yaml.'), '']
    table = section['table']
    if table is None:
        return lines
    test = {(b['low_c'], b['high_c']): b for b in section['test_bias'] or ()}
    header = ('temperature bin (C)', 'mean T (C)', *(f'{a} written' for a in axes))
    if test:
        header += tuple(f'{a} test' for a in axes)
    lines += ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    for k, (temperature, (low, high)) in enumerate(zip(table['temperature_c'],
                                                       table['bins_c'])):
        row = [f'{low:.1f} .. {high:.1f}', f'{temperature:.1f}',
               *(_e(table['error_rad_s'][a][k]) for a in axes)]
        if test:
            part = test.get((low, high))
            row += [_e(part['rms'][a] if part else None) for a in axes]
        lines.append('| ' + ' | '.join(str(cell) for cell in row) + ' |')
    lines.append('')
    if test:
        lines += ['test: the same bias part of the written model on the test part, which no '
                  'fit saw.', '']
    if covariance is not None:
        lines += [normalised_text(covariance) + ', on the test part.', '']
    return lines


def console_lines(report: dict) -> list:
    """Give the console's lines on the fitted range and the error by temperature."""
    section = report['outside_fitted_range']
    per_axis = section['per_axis']
    overall = section['forward_all']
    outside = [b['block'] for b in section['forward_blocks']
               if max(b['fraction'].values()) > 0.0]
    text = (f'outside the fitted temperature range (clamped): forward held-out blocks '
            f'{fraction_text(overall["fraction"], per_axis)} of {overall["rows"]} rows'
            + (f' (blocks {", ".join(str(b) for b in outside)})' if outside else ''))
    if 'deciding_scheme' in section:
        deciding = section['deciding_all']
        text += (f'; {section["deciding_scheme"].replace("_", "-")} held-out blocks '
                 f'{fraction_text(deciding["fraction"], per_axis)} of {deciding["rows"]} rows')
    test = section['test']
    if test is not None:
        text += f'; test set {fraction_text(test["fraction"], per_axis)} of {test["rows"]} rows'
    table = report['error_by_temperature']['table']
    lines = [text]
    for axis in report['axes'] if table else ():
        cells = ', '.join(f'{t:.1f} C {_e(v)}' for t, v in zip(table['temperature_c'],
                                                               table['error_rad_s'][axis]))
        lines.append(f'axis {axis}: model error by temperature (rad/s, model_error.*): {cells}')
    return lines


def block_lines(blocks, scheme: str) -> list:
    """Lines for ``fit``: how much of each held-out block lies outside its training range."""
    predicted = [(k, part) for k, part in enumerate(blocks) if part is not None]
    rows = sum(part.rows for _, part in predicted)
    outside = sum(part.rows * part.fraction[0] for _, part in predicted)
    lines = [f'held-out rows outside the temperature range of their training blocks '
             f'(clamped): {percent(outside / rows if rows else 0.0)} of {rows} ({scheme})']
    lines += [f'  block {k}: {percent(part.fraction[0])} of {part.rows} rows outside '
              f'{part.low_c:.2f} .. {part.high_c:.2f} C'
              + (f', at most {part.furthest_c[0]:.2f} C beyond' if part.furthest_c[0] else '')
              for k, part in predicted if part.fraction[0] > 0.0]
    return lines


def plot_error_by_temperature(path, diagnosis, save) -> None:
    """
    Plot per axis the model error written by temperature, the test part's, and the cubic's.

    One panel per axis on one log scale: the table params.yaml carries (the
    bias part, `model_error.larger_table`), the same bias part of the written
    model on the test part, and of PX4's cubic clamped at its range (on the
    test part, else on the held-out blocks), the reference; the white noise
    of a sample dash-dotted. The legend lies below the panels.
    """
    from matplotlib import pyplot

    errors = diagnosis.error_by_temperature
    axes = diagnosis.axes
    figure, grid = pyplot.subplots(1, len(axes), figsize=(4.2 * len(axes), 4.6), squeeze=False,
                                   sharey=True, layout='constrained')
    where = 'test part' if errors.test is not None else 'held-out'
    curves = [(errors.test, 'x--', 'C3', 'written model, test part'),
              (errors.cubic, '+:', '0.4', f"PX4's cubic, clamped, {where}")]
    for k, (plot, name) in enumerate(zip(grid[0], axes)):
        if errors.table is not None:
            plot.semilogy(errors.table.temperature_c, errors.table.error_rad_s[k], 'o-',
                          color='C0', label='model_error written (held-out)')
        for table, style, colour, label in curves:
            if table is None:
                continue
            filled = list(table.filled())
            bias = bias_rms_rad_s(table, errors.noise_rad_s)[:, k]
            plot.semilogy([table.temperature_c[i] for i in filled], bias[filled], style,
                          color=colour, label=label)
        plot.axhline(errors.noise_rad_s[k], color='0.6', ls='-.',
                     label='white noise of a sample')
        plot.set_title(f'axis {name}')
        plot.set_xlabel('temperature (C)')
        plot.grid(True, which='both', alpha=0.3)
    grid[0][0].set_ylabel('bias part of the RMS (rad/s)')
    figure.suptitle('Error of the written model by temperature (noise share taken out)')
    handles, labels = grid[0][0].get_legend_handles_labels()
    figure.legend(handles, labels, loc='outside lower center', ncol=min(len(labels), 4),
                  fontsize='small')
    save(pyplot, figure, path)
