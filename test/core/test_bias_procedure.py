"""The ADIS16130 bias procedure of AN-1042: core state machine and ``mlx-tempcomp adis-bias``."""

import math
import os
import signal
import subprocess
import sys

from cli_checks import assert_user_error, node_values
from mlx_tempcomp.cli import main
from mlx_tempcomp.core.effects import LinearBtc
from mlx_tempcomp.core.errors import CalibrationError
from mlx_tempcomp.core.procedures.adis16130_bias import (averaging_time_s, BiasPoint,
                                                         BiasProcedure, btc_rad_s_per_c,
                                                         MIN_WINDOW_SAMPLES, Phase,
                                                         ProcedureSettings, short_window)
from mlx_tempcomp.core.series.noise import allan_deviation, NoiseFigures
from mlx_tempcomp.parameters.models import build_model
from mlx_tempcomp.simulation.adis16130 import (ADIS16130_NOISE, Adis16130Truth,
                                               self_heating_profile)
from mlx_tempcomp.sources.adis16130 import SimulatedSensor, SimulationConfig
from mlx_tempcomp.toolkit.tables import format_btc_table
import numpy as np
import pytest

# AN-1042 Table 6: TBIAS 0.04 deg/s/C, (TEMP - T3) in 0.02 C steps -> (TEMP - T3) x BTC.
TABLE_6 = ((0.12, -0.0048), (0.10, -0.0040), (0.08, -0.0032), (0.06, -0.0024),
           (0.04, -0.0016), (0.02, -0.0008), (0.0, 0.0), (-0.02, 0.0008), (-0.04, 0.0016),
           (-0.06, 0.0024), (-0.08, 0.0032), (-0.10, 0.0040), (-0.12, 0.0048))
RATE_HZ = 250.0
# Short phases: 10 s points as in the note, the waits long against the simulated
# part's 120 s self-heating time constant, a 60 s rest record, a 30 s PBC window.
SHORT = {'average_s': 10.0, 'self_heat_s': 600.0, 'settle_s': 600.0, 'allan_record_s': 60.0,
         'pbc_s': 30.0}
# 1-sigma error of a window's mean rate on the simulated part (deg/s): the white
# noise averaged over the window plus the Gauss-Markov bias instability, which
# the window (far shorter than its 100 s correlation time) does not average.
WHITE_DPS = ADIS16130_NOISE.white_sigma_dps
WANDER_DPS = ADIS16130_NOISE.bias_instability_dps
SIGMAS = 4.0


def window_sigma_dps(seconds, rate_hz=RATE_HZ):
    return math.hypot(WHITE_DPS / math.sqrt(seconds * rate_hz), WANDER_DPS)


def allan_figures(time_s, rate_rad_s):
    return allan_deviation(time_s, rate_rad_s.reshape(-1, 1), ('z',))[0]


def simulated(slope_dps_per_c, seed=0, rise_c=5.0):
    return SimulatedSensor(SimulationConfig(
        seed=seed, truth=Adis16130Truth(bias_dps_per_c=slope_dps_per_c),
        thermal=self_heating_profile(rise_c=rise_c)))


def drive(procedure, sensor, rate_hz=RATE_HZ):
    """Read the sensor at rate_hz in the windows, jump over the waits; return the result."""
    next_s = sensor.clock.now_s
    while procedure.phase is not Phase.DONE:
        sample = sensor.read()
        procedure.add(sample.time_s, sample.rate_rad_s[0], sample.temperature_c[0])
        next_s = procedure.phase_end_s if procedure.phase.is_wait else next_s + 1.0 / rate_hz
        if procedure.phase is not Phase.DONE:
            sensor.advance_to(next_s)
    return procedure.result


def test_table_6_of_the_note():
    # A +0.04 deg/s/C bias slope between two points gives BTC = -0.04 deg/s/C ...
    p1 = BiasPoint(temperature_c=25.0, bias_rad_s=math.radians(0.1), samples=100,
                   duration_s=10.0)
    p2 = BiasPoint(temperature_c=30.0, bias_rad_s=math.radians(0.1 + 5 * 0.04), samples=100,
                   duration_s=10.0)
    btc = btc_rad_s_per_c(p1, p2)
    assert math.degrees(btc) == pytest.approx(-0.04, rel=1e-12)
    # ... and the correction factors of Table 6, from the model and from the printed table.
    model = LinearBtc(pbc_rad_s=(0.0,), btc_rad_s_per_c=(btc,), t3_c=26.0).model()
    offsets_c = np.array([row[0] for row in TABLE_6])
    corrections = model.correct(np.zeros((len(TABLE_6), 1)), 26.0 + offsets_c).rate_rad_s
    np.testing.assert_allclose(np.degrees(corrections[:, 0]), [row[1] for row in TABLE_6],
                               atol=1e-12)
    printed = [line.split() for line in format_btc_table(model, ('z',), 0.02).splitlines()[1:]]
    # Columns: TEMP - T3, the correction in rad/s, and beside it in deg/s as the note prints.
    assert [float(cell) for row in printed for cell in (row[0], row[2])] == \
        pytest.approx([value for row in TABLE_6 for value in row], abs=1e-12)
    assert [float(row[1]) for row in printed] == \
        pytest.approx([math.radians(row[1]) for row in TABLE_6], rel=1e-3)


def test_btc_refuses_too_small_a_temperature_change():
    p1 = BiasPoint(temperature_c=25.01, bias_rad_s=0.0, samples=100, duration_s=10.0)
    p2 = BiasPoint(temperature_c=25.31, bias_rad_s=1e-4, samples=100, duration_s=10.0)
    with pytest.raises(CalibrationError, match=r'T1 25\.010 C and T2 25\.310 C differ by 0\.300'):
        btc_rad_s_per_c(p1, p2)
    assert btc_rad_s_per_c(p1, p2, min_change_c=0.25) == pytest.approx(-1e-4 / 0.3)


def figures_with_minimum_at(tau_s):
    taus = 2.0 ** np.arange(-3, 12)
    return NoiseFigures(axis='z', taus_s=taus, adev_rad_s=np.ones_like(taus),
                        angle_random_walk_rad_s_rt_hz=1.0, bias_instability_rad_s=1.0,
                        bias_instability_tau_s=tau_s, rate_noise_rad_s=1.0, duration_s=4096.0)


def test_averaging_time_is_the_allan_minimum_clipped():
    # Below the note's default, the default; beyond a tenth of the record, that tenth.
    assert averaging_time_s(figures_with_minimum_at(64.0), 150.0, 6000.0) == 150.0
    assert averaging_time_s(figures_with_minimum_at(512.0), 150.0, 6000.0) == 512.0
    assert averaging_time_s(figures_with_minimum_at(1024.0), 150.0, 6000.0) == 600.0
    # The PBC window follows it unless fixed.
    settings = ProcedureSettings(allan_record_s=6000.0)
    assert settings.pbc_window_s(None) == 150.0
    assert settings.pbc_window_s(figures_with_minimum_at(512.0)) == 512.0
    assert ProcedureSettings(pbc_s=30.0).pbc_window_s(figures_with_minimum_at(512.0)) == 30.0


def synthetic(procedure, start_s, stop_s, rate_hz, rate, temperature, rng, noise_rad_s):
    """Feed rate(t) + white noise and temperature(t) from start_s up to stop_s."""
    for t in np.arange(start_s, stop_s, 1.0 / rate_hz):
        procedure.add(t, rate(t) + noise_rad_s * rng.standard_normal(), temperature(t))


def test_short_window_names_the_first_window_too_short():
    assert short_window(100.0, 10.0, None, 60.0) is None
    assert short_window(100.0, 0.05, 0.05, 0.5) == (
        'average_s', 0.05, f'gives fewer than {MIN_WINDOW_SAMPLES} samples')
    assert short_window(100.0, 10.0, 0.05, 0.5)[:2] == ('pbc_s', 0.05)
    name, seconds, why = short_window(100.0, 10.0, 150.0, 0.5)
    assert (name, seconds) == ('allan_record_s', 0.5)
    assert why.endswith('samples an Allan deviation needs (0 skips it)')
    assert short_window(100.0, 10.0, 150.0, 0.0) is None     # no rest record


def test_phases_and_points_on_a_known_stream():
    """Noise-free linear bias: every phase in order, the exact points, BTC, PBC and T3."""
    settings = ProcedureSettings(average_s=2.0, self_heat_s=5.0, settle_s=3.0, pbc_s=4.0)
    procedure = BiasProcedure(settings)
    slope = 1e-3                                          # rad/s/C

    def temperature(t):
        return 25.0 + 0.5 * min(t - 100.0, 8.0)           # +4 C by the end of the wait

    seen = []
    for t in np.arange(100.0, 116.0, 0.01):
        phase = procedure.add(t, 2e-3 + slope * (temperature(t) - 25.0), temperature(t))
        if not seen or seen[-1] is not phase:
            seen.append(phase)
    assert seen == [Phase.POINT_1, Phase.SELF_HEAT, Phase.POINT_2, Phase.SETTLE, Phase.PBC]
    assert procedure.progress == pytest.approx(3.99 / 4.0)
    procedure.add(114.0, 0.0, 25.0)                       # time going back: skipped
    procedure.add(117.0, math.nan, 25.0)                  # not finite: skipped
    procedure.add(117.5, 0.0, 25.0)                       # closes the PBC window
    assert procedure.phase is Phase.DONE
    assert procedure.skipped == {'non-finite': 1, 'time not increasing': 1}
    result = procedure.result
    assert result.point_1.samples == 200 and result.point_1.temperature_c == \
        pytest.approx(25.0 + 0.5 * 0.995)
    assert result.btc_rad_s_per_c == pytest.approx(-slope, rel=1e-9)
    assert result.t3_c == pytest.approx(29.0) and result.pbc_rad_s == pytest.approx(-6e-3)
    assert result.pbc_point.samples == 400 and result.noise is None
    assert result.model == LinearBtc(pbc_rad_s=(result.pbc_rad_s,),
                                     btc_rad_s_per_c=(result.btc_rad_s_per_c,),
                                     t3_c=result.t3_c).model()


@pytest.mark.parametrize('moving', [False, True])
def test_motion_check_refuses_a_rotating_window(moving):
    """A 3 deg/s turn back and forth in point 2 is refused once the rest record gives the noise."""
    rng = np.random.default_rng(1)
    noise_rad_s = 0.004
    settings = ProcedureSettings(average_s=2.0, self_heat_s=1.0, settle_s=20.0,
                                 allan_record_s=20.0, pbc_s=2.0)
    procedure = BiasProcedure(settings, allan_figures)

    def rate(t):
        turning = moving and 3.0 <= t < 5.0
        return math.radians(3.0) * math.sin(2 * math.pi * t) if turning else 0.0

    synthetic(procedure, 0.0, 9.0, 200.0, rate, lambda t: 25.0 + t, rng, noise_rad_s)
    assert procedure.phase is Phase.REST_RECORD and procedure.point_2 is not None
    if not moving:
        synthetic(procedure, 9.0, 28.0, 200.0, rate, lambda t: 34.0, rng, noise_rad_s)
        assert procedure.phase is Phase.DONE
        assert procedure.rate_noise_rad_s == pytest.approx(noise_rad_s, rel=0.1)
        return
    with pytest.raises(CalibrationError, match=r'moved during the point_2 window: .* '
                                               r'motion_noise_multiple 2'):
        synthetic(procedure, 9.0, 28.0, 200.0, rate, lambda t: 34.0, rng, noise_rad_s)


def test_motion_check_with_a_known_noise_refuses_at_once():
    rng = np.random.default_rng(2)
    procedure = BiasProcedure(ProcedureSettings(average_s=1.0, rate_noise_rad_s=0.004))
    synthetic(procedure, 0.0, 1.0, 200.0, lambda t: 0.05 * math.sin(6.0 * t), lambda t: 25.0,
              rng, 0.004)
    with pytest.raises(CalibrationError, match='point_1 window'):
        procedure.add(1.0, 0.0, 25.0)


@pytest.mark.parametrize('slope_dps_per_c', [0.04, -0.04])
def test_btc_and_pbc_on_the_simulated_part(slope_dps_per_c):
    """
    The note's procedure on the simulated part recovers its bias slope and its bias at T3.

    Tolerance: 4 sigma of the window means (white noise and bias instability,
    `window_sigma_dps`); BTC is their difference over T2 - T1.
    """
    procedure = BiasProcedure(ProcedureSettings(**SHORT), allan_figures)
    result = drive(procedure, simulated(slope_dps_per_c, seed=3))
    p1, p2 = result.point_1, result.point_2
    assert p1.samples == pytest.approx(10 * RATE_HZ, abs=1)
    assert 4.5 < p2.temperature_c - p1.temperature_c < 5.0
    btc_tolerance = SIGMAS * math.sqrt(2) * window_sigma_dps(10.0) / (p2.temperature_c
                                                                      - p1.temperature_c)
    assert math.degrees(result.btc_rad_s_per_c) == pytest.approx(-slope_dps_per_c,
                                                                 abs=btc_tolerance)
    assert btc_tolerance < 0.2 * abs(slope_dps_per_c)
    # Truth: bias(T) = slope (T - 25 C); PBC is minus the bias at T3.
    assert result.t3_c == pytest.approx(30.0, abs=0.01)
    assert math.degrees(result.pbc_rad_s) == pytest.approx(
        -slope_dps_per_c * (result.t3_c - 25.0), abs=SIGMAS * window_sigma_dps(30.0))
    # The rest record gives the white noise of one sample.
    assert math.degrees(result.noise.rate_noise_rad_s) == pytest.approx(WHITE_DPS, rel=0.1)


def adis_bias(tmp_path, *options):
    out = tmp_path / 'adis.yaml'
    options = ['--average-s', '10', '--self-heat-s', '600', '--settle-s', '600',
               '--allan-record-s', '60', '--pbc-s', '30', '--rate-hz', str(RATE_HZ), *options]
    return main(['adis-bias', '--out', str(out), *options]), out


def test_cli_writes_parameters_that_flatten_the_simulated_bias(tmp_path, capsys):
    code, out = adis_bias(tmp_path, '--source', 'simulated', '--seed', '5')
    printed = capsys.readouterr().out
    assert code == 0
    for needle in ('T1 = ', 'T2 = ', 'BTC = ', 'PBC = ', 'T3 = ', 'rate_noise_rad_s',
                   'as Table 6 of the note', f'wrote {out} (model linear_btc'):
        assert needle in printed
    values = node_values(out)
    assert isinstance(values['rate_noise_rad_s'], float)
    assert math.degrees(values['rate_noise_rad_s']) == pytest.approx(WHITE_DPS, rel=0.1)
    model = build_model(values)
    assert model.name == 'linear_btc' and values['axes'] == ['z']
    # A fresh warm-up of another part with the same slope (0.04 deg/s/C, 25 -> 30 C) at 50 Hz.
    sensor = simulated(0.04, seed=11)
    record = sensor.record(300.0, 50.0)
    corrected = model.correct(record.rate_rad_s, record.temperature_c).rate_rad_s[:, 0]

    def slope_dps_per_c(rate_rad_s):
        return math.degrees(np.polyfit(record.temperature_c, rate_rad_s, 1)[0])

    assert slope_dps_per_c(record.rate_rad_s[:, 0]) == pytest.approx(0.04, abs=0.005)
    # Left: the BTC error (about 0.001 deg/s/C, 1 sigma) and the record's own slope noise
    # (0.22 deg/s over 15000 samples spread 1.3 C: 0.0014 deg/s/C, plus bias wander).
    assert abs(slope_dps_per_c(corrected)) < 0.006
    assert abs(math.degrees(np.mean(corrected))) < SIGMAS * window_sigma_dps(300.0, 50.0)


def assert_refused(code, capsys, out, *needles):
    assert_user_error(code, capsys, *needles)
    assert not out.exists()


def test_cli_refuses_too_small_a_temperature_change(tmp_path, capsys):
    code, out = adis_bias(tmp_path, '--source', 'simulated', '--self-heat-rise-c', '0')
    assert_refused(code, capsys, out, 'T1 ', 'T2 ', 'did not warm itself')


def test_cli_spidev_without_a_device(tmp_path, capsys):
    code, out = adis_bias(tmp_path, '--source', 'spidev', '--bus', '97')
    assert_refused(code, capsys, out, '/dev/spidev97.0')
    code, out = adis_bias(tmp_path, '--source', 'spidev', '--bias-slope-dps-per-c', '0.1')
    assert_refused(code, capsys, out, '--bias-slope-dps-per-c does not apply')


def test_cli_ctrl_c_writes_nothing(tmp_path):
    out = tmp_path / 'adis.yaml'
    process = subprocess.Popen(
        [sys.executable, '-m', 'mlx_tempcomp.cli', 'adis-bias', '--source', 'simulated',
         '--time-scale', '1', '--rate-hz', '50', '--out', str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, 'PYTHONUNBUFFERED': '1'},
        # As from a terminal: a suite started in the background of a script inherits SIGINT
        # ignored, and Python then installs no KeyboardInterrupt for it.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        # Interrupted in the first window, after the first phase was announced.
        while not process.stdout.readline().startswith('phase point_1'):
            pass
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=20)
    finally:
        process.kill()
    assert process.returncode == 130
    assert err.strip() == 'interrupted: nothing written'
    assert not out.exists()
