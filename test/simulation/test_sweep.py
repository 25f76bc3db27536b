"""The -40..85 C sweep: simulated device, SPI driver, compensation with its own EEPROM."""

# The acceptance figure: the EEPROM-compensated ZRO error is at least
# 3x smaller (RMS) than that of the nominal conversion. Run with ``pytest -s``
# to see the figures.

import math

from mlx_tempcomp.simulation.sweep import format_population, format_report, main, run_sweep
import numpy as np
import pytest

REQUIRED_RATIO = 3.0


def test_default_device_compensated_rms_is_three_times_smaller():
    result = run_sweep()
    ratio = result.nominal.rms / result.eeprom.rms
    figure = (f'default device (seed 0, 1800 s, oversample 16): nominal RMS '
              f'{result.nominal.rms:.3f} deg/s, EEPROM RMS {result.eeprom.rms:.3f} deg/s, '
              f'ratio {ratio:.2f}x')
    print(figure)
    assert ratio >= REQUIRED_RATIO, figure
    # What the sweep really covered, read through the driver.
    assert len(result.rate_code) == 3600 == result.eeprom.samples == result.nominal.samples
    assert result.fields.version == 2 and result.fields.full_scale_dps == 75.0
    assert result.fields.total_outvoted_bits == 0
    assert not result.saturated.any()
    assert result.temperature_c.min() < -35.0 and result.temperature_c.max() > 80.0
    assert np.all(np.diff(result.time_s) == pytest.approx(0.5))
    # Only the soaks beyond the calibration points are clamped to [TC0, TC2].
    assert 0 < result.clamped_samples < 0.1 * len(result.rate_code)
    report = format_report(result)
    assert f'RMS improvement: {ratio:.1f}x' in report
    assert '3600 readings' in report


@pytest.mark.slow
def test_population_pooled_rms_ratio():
    nominal, eeprom, results = [], [], []
    for seed in range(10):
        result = run_sweep(seed=seed, duration_s=1200.0, period_s=0.5, oversample=8)
        results.append(result)
        assert len(result.rate_code) == 2400
        assert not result.saturated.any()
        nominal.append(result.nominal.rms)
        eeprom.append(result.eeprom.rms)
        print(f'seed {seed}: nominal RMS {result.nominal.rms:.3f}, EEPROM RMS '
              f'{result.eeprom.rms:.3f} deg/s, ratio {nominal[-1] / eeprom[-1]:.2f}x')
    pooled_nominal = math.sqrt(np.mean(np.square(nominal)))
    pooled_eeprom = math.sqrt(np.mean(np.square(eeprom)))
    ratio = pooled_nominal / pooled_eeprom
    figure = (f'population of 10 (1200 s, oversample 8): pooled nominal RMS '
              f'{pooled_nominal:.3f} deg/s, pooled EEPROM RMS {pooled_eeprom:.3f} deg/s, '
              f'ratio {ratio:.2f}x')
    print(figure)
    assert ratio >= REQUIRED_RATIO, figure
    pooled_row = format_population(range(10), results).splitlines()[-1].split()
    assert pooled_row == ['pooled', f'{pooled_nominal:.3f}', f'{pooled_eeprom:.3f}',
                          f'{ratio:.1f}x']


def test_version_0_device_falls_back_to_nominal():
    result = run_sweep(seed=3, duration_s=300.0, oversample=4, version=0)
    assert result.fields.version == 0 and not result.fields.has_table
    assert result.fields.full_scale_dps == 75.0
    assert result.eeprom == result.nominal
    assert result.clamped_samples == 0
    assert result.eeprom.samples == 600


def test_sweep_is_reproducible():
    a = run_sweep(seed=4, duration_s=60.0, oversample=2)
    b = run_sweep(seed=4, duration_s=60.0, oversample=2)
    np.testing.assert_array_equal(a.rate_code, b.rate_code)
    np.testing.assert_array_equal(a.temperature_code, b.temperature_code)
    assert a.eeprom == b.eeprom and a.fields == b.fields


def test_sweep_command_prints_the_report(capsys):
    assert main(['--seed', '1', '--duration', '120', '--oversample', '2']) == 0
    out = capsys.readouterr().out
    assert out.startswith('EEPROM: VERSION 2, full scale 75 deg/s')
    assert '240 readings' in out
    assert 'nominal (AN2 method 1)' in out and 'EEPROM table (method 4)' in out
    assert 'RMS improvement: ' in out


@pytest.mark.parametrize('argv', [['--duration', '0'], ['--period', '-1'],
                                  ['--oversample', '0']])
def test_sweep_command_rejects_bad_numbers(argv, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert 'error: --duration and --period must be positive, --oversample' in err
    assert 'Traceback' not in err
