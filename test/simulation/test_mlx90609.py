"""The simulated MLX90609: seeding, clock pacing and the optional physical effects."""

import math
import time

from mlx_tempcomp.hardware.mlx90609 import Mlx90609, Mlx90609Reading
from mlx_tempcomp.simulation.clock import SimClock
from mlx_tempcomp.simulation.mlx90609 import simulated_device
from mlx_tempcomp.simulation.physics import (
    Effects, GRAVITY_M_S2, GyroPhysics, GyroTruth, Noise, Scenario, ThermalProfile)
import numpy as np
import pytest

QUIET = Noise(density_dps_rt_hz=0.0, bias_instability_dps=0.0, temperature_noise_mv=0.0)
# Zero-noise codes at 25 C and zero rate (see test_hardware_mlx90609.py).
ZERO_RATE_CODE = 1008
CODE_25C = 1408
LSB_PER_DPS = 12.8       # 75 deg/s part: 2000 mV / 75 deg/s x 12/25 LSB/mV
ZRO = (0.3, 0.01, -2e-4)


def quiet_physics(effects, scenario=Scenario()):
    return GyroPhysics(GyroTruth(zro_dps_coefficients=ZRO, effects=effects, noise=QUIET),
                       scenario, seed=0)


def readings(driver, count, period_s=0.01, oversample=1):
    out = []
    clock = driver.transport.device.clock
    for _ in range(count):
        start = clock.now_s
        out.append(driver.read(oversample))
        driver.transport.wait(period_s - (clock.now_s - start))
    return out


# --- seeding ---------------------------------------------------------------------------------

def noisy_run(seed, count=200):
    truth = GyroTruth.random(np.random.default_rng(3))
    scenario = Scenario(thermal=ThermalProfile.sweep(duration_s=10.0, soak_s=1.0))
    device = simulated_device(truth, scenario, seed=seed)
    driver = Mlx90609(device.transport())
    return driver.read_eeprom(), readings(driver, count, period_s=0.05)


def test_same_seed_gives_identical_readings():
    image_a, run_a = noisy_run(seed=5)
    image_b, run_b = noisy_run(seed=5)
    assert image_a == image_b
    assert run_a == run_b
    # With noise on, the readings do vary within the run: the equality is not trivial.
    assert len({r.rate_code for r in run_a}) > 5


def test_different_seed_gives_different_readings():
    image_a, run_a = noisy_run(seed=5)
    image_b, run_b = noisy_run(seed=6)
    assert image_a != image_b
    differing = sum(a.rate_code != b.rate_code for a, b in zip(run_a, run_b))
    assert differing > len(run_a) // 2


def test_physics_alone_is_seedable():
    truth = GyroTruth()
    a, b, c = (GyroPhysics(truth, Scenario(), seed=s) for s in (1, 1, 2))
    times = np.linspace(0.001, 1.0, 50)
    out_a = [a.rate_output_mv(t) for t in times]
    assert out_a == [b.rate_output_mv(t) for t in times]
    assert out_a != [c.rate_output_mv(t) for t in times]


# --- clock -----------------------------------------------------------------------------------

def test_unpaced_clock_runs_much_faster_than_real_time():
    scenario = Scenario(thermal=ThermalProfile.sweep(duration_s=60.0, soak_s=5.0))
    device = simulated_device(GyroTruth(), scenario, seed=0, clock=SimClock(None))
    driver = Mlx90609(device.transport())
    start = time.monotonic()
    run = readings(driver, 600, period_s=0.1)
    wall_s = time.monotonic() - start
    assert device.clock.now_s == pytest.approx(60.0, abs=1e-6)
    assert len(run) == 600 and not any(r.saturated for r in run)
    assert wall_s < 6.0, f'60 s simulated took {wall_s:.2f} s of wall time'


def test_paced_clock_follows_the_real_time_factor():
    # Factor 10: 0.5 simulated seconds must take at least 50 ms of wall time.
    start = time.monotonic()
    clock = SimClock(real_time_factor=10.0)
    device = simulated_device(GyroTruth(noise=QUIET), Scenario(), seed=0, clock=clock)
    driver = Mlx90609(device.transport())
    run = readings(driver, 50, period_s=0.01)
    wall_s = time.monotonic() - start
    assert clock.now_s == pytest.approx(0.5, abs=1e-6)
    assert run[-1] == Mlx90609Reading(ZERO_RATE_CODE, CODE_25C, False)
    assert 0.05 <= wall_s < 0.4, f'0.5 s at factor 10 took {wall_s * 1e3:.1f} ms'


@pytest.mark.parametrize('factor', [0.0, -1.0])
def test_clock_refuses_a_non_positive_factor(factor):
    with pytest.raises(ValueError, match=f'^real_time_factor must be positive, got {factor}$'):
        SimClock(real_time_factor=factor)


def test_clock_never_runs_backwards():
    clock = SimClock()
    clock.advance(2.5)
    clock.advance(-1.0)
    clock.advance(0.0)
    assert clock.now_s == 2.5


# --- optional effects, in the physics --------------------------------------------------------

def test_thermal_lag_delays_the_sensed_temperature_by_rate_times_tau():
    # Ramp 0.1 C/s from 100 s to 400 s; the sensor lags the die with tau = 20 s.
    scenario = Scenario(thermal=ThermalProfile(times_s=(0.0, 100.0, 400.0, 1000.0),
                                               temperatures_c=(25.0, 25.0, 55.0, 55.0)))
    physics = quiet_physics(Effects(thermal_lag_s=20.0), scenario)
    reference = quiet_physics(Effects(), scenario)
    for t in np.arange(0.1, 300.05, 0.1):
        physics.advance(t)
        reference.advance(t)
    state = physics.state
    assert state.die_c == pytest.approx(45.0)
    assert state.die_c - state.sensor_c == pytest.approx(0.1 * 20.0, rel=0.01)
    assert reference.state.sensor_c == reference.state.die_c == state.die_c
    # The temperature output follows the sensor, not the die: 10 mV/K below.
    assert physics.temperature_output_mv(300.0) == pytest.approx(
        reference.temperature_output_mv(300.0) - 20.0, rel=1e-3)
    for t in np.arange(300.1, 700.05, 0.1):
        physics.advance(t)
    assert physics.state.sensor_c == pytest.approx(55.0, abs=0.01)


def test_hysteresis_separates_heating_from_cooling_at_the_same_temperature():
    # 0 -> 60 -> 0 C at 6 C/min: 30 C is crossed at 300 s heating and 900 s cooling.
    scenario = Scenario(thermal=ThermalProfile.cycle((60.0, 0.0), rate_c_per_min=6.0,
                                                     start_c=0.0))
    physics = quiet_physics(Effects(hysteresis_dps=0.4, hysteresis_width_c=5.0), scenario)
    offsets = {}
    for t in np.arange(1.0, 1200.5, 1.0):
        physics.advance(t)
        if t in (300.0, 900.0):
            assert physics.state.die_c == pytest.approx(30.0)
            offsets[t] = physics.zro_offset_dps()
    truth = physics.truth
    assert offsets[300.0] - offsets[900.0] == pytest.approx(0.4, rel=0.02)
    assert offsets[300.0] == pytest.approx(truth.zro_dps(30.0) + 0.2, abs=0.01)
    assert offsets[900.0] == pytest.approx(truth.zro_dps(30.0) - 0.2, abs=0.01)


def test_hysteresis_switches_branch_over_about_its_width():
    # Heat 0 -> 60 C, then cool: half a width (2.5 C) into the reversal the branch
    # has moved from +h/2 by h x (1 - exp(-0.5)), to about 0.04 deg/s.
    scenario = Scenario(thermal=ThermalProfile.cycle((60.0, 0.0), rate_c_per_min=6.0,
                                                     start_c=0.0))
    physics = quiet_physics(Effects(hysteresis_dps=0.4, hysteresis_width_c=5.0), scenario)
    for t in np.arange(1.0, 600.5, 1.0):
        physics.advance(t)
    assert physics.state.hysteresis_dps == pytest.approx(0.2, abs=1e-3)
    for t in np.arange(601.0, 625.5, 1.0):
        physics.advance(t)
    assert physics.state.die_c == pytest.approx(57.5)
    assert physics.state.hysteresis_dps == pytest.approx(0.4 * (math.exp(-0.5) - 0.5),
                                                         abs=0.005)


def test_hysteresis_off_gives_the_same_offset_both_ways():
    scenario = Scenario(thermal=ThermalProfile.cycle((60.0, 0.0), rate_c_per_min=6.0,
                                                     start_c=0.0))
    physics = quiet_physics(Effects(), scenario)
    physics.advance(300.0)
    heating = physics.zro_offset_dps()
    physics.advance(900.0)
    assert physics.zro_offset_dps() == pytest.approx(heating, abs=1e-12)


def test_supply_voltage_shifts_the_zro():
    scenario = Scenario(supply_times_s=(0.0, 10.0, 20.0), supply_v=(5.0, 5.0, 5.5))
    physics = quiet_physics(Effects(zro_supply_dps_per_v=0.5), scenario)
    base = physics.truth.zro_dps(25.0)
    assert base == pytest.approx(0.3)
    expected = {5.0: base, 15.0: base + 0.125, 20.0: base + 0.25, 30.0: base + 0.25}
    for t, offset in expected.items():
        physics.advance(t)
        assert physics.zro_offset_dps() == pytest.approx(offset, abs=1e-12), t


def test_bias_steps_appear_at_their_time():
    physics = quiet_physics(Effects(bias_steps=((10.0, 0.5), (20.0, -0.2))))
    expected = {9.999: 0.3, 10.0: 0.8, 19.999: 0.8, 20.0: 0.6, 100.0: 0.6}
    for t, offset in expected.items():
        physics.advance(t)
        assert physics.zro_offset_dps() == pytest.approx(offset, abs=1e-12), t


@pytest.mark.parametrize('acceleration, offset', [
    ((0.0, 0.0, GRAVITY_M_S2), 0.05 * GRAVITY_M_S2),       # flat
    ((GRAVITY_M_S2, 0.0, 0.0), 0.01 * GRAVITY_M_S2),       # on its side
    ((1.0, 2.0, 0.0), 0.05),
])
def test_acceleration_sensitivity(acceleration, offset):
    scenario = Scenario(acceleration_m_s2=acceleration)
    physics = quiet_physics(Effects(acceleration_dps_per_m_s2=(0.01, 0.02, 0.05)), scenario)
    physics.advance(1.0)
    assert physics.zro_offset_dps() == pytest.approx(0.3 + offset, abs=1e-12)


def test_effects_are_off_by_default():
    scenario = Scenario(supply_times_s=(0.0,), supply_v=(4.0,),
                        acceleration_m_s2=(5.0, 5.0, 5.0),
                        thermal=ThermalProfile(times_s=(0.0, 100.0),
                                               temperatures_c=(25.0, 35.0)))
    physics = quiet_physics(Effects(), scenario)
    physics.advance(50.0)
    assert physics.state.sensor_c == physics.state.die_c == pytest.approx(30.0)
    assert physics.zro_offset_dps() == pytest.approx(physics.truth.zro_dps(30.0), abs=1e-12)


def test_rate_output_clips_at_the_rails():
    scenario = Scenario(rate_times_s=(0.0, 1.0), rate_dps=(500.0, -500.0))
    physics = GyroPhysics(GyroTruth(noise=QUIET), scenario, seed=0)
    assert physics.rate_output_mv(0.0) == 4750.0
    assert physics.rate_output_mv(0.5) == pytest.approx(2500.0)
    assert physics.rate_output_mv(1.0) == 250.0


def test_white_noise_sigma_matches_the_density():
    truth = GyroTruth(noise=Noise(bias_instability_dps=0.0))
    physics = GyroPhysics(truth, Scenario(), seed=4)
    samples = np.array([physics.rate_output_mv(t) for t in np.arange(1, 20001) * 1e-3])
    sigma_dps = np.std(samples) / truth.typical_sf_mv
    # 0.03 deg/s/sqrt(Hz) over pi/2 x 75 Hz.
    assert sigma_dps == pytest.approx(0.03 * math.sqrt(math.pi / 2.0 * 75.0), rel=0.03)


# --- effects seen through the device and the driver ------------------------------------------

def quiet_driver(effects, scenario=Scenario()):
    truth = GyroTruth(effects=effects, noise=QUIET)
    return Mlx90609(simulated_device(truth, scenario, seed=0).transport())


def test_bias_step_seen_through_the_driver():
    driver = quiet_driver(Effects(bias_steps=((0.1, 5.0),)))
    before = readings(driver, 9, period_s=0.01)
    after = readings(driver, 5, period_s=0.01)
    assert {r.rate_code for r in before} == {ZERO_RATE_CODE}
    # 5 deg/s x 12.8 LSB/(deg/s) = 64 LSB.
    assert {r.rate_code for r in after[1:]} == {ZERO_RATE_CODE + 64}


def test_supply_shift_seen_through_the_driver():
    scenario = Scenario(supply_times_s=(0.0, 0.05), supply_v=(5.0, 4.5))
    driver = quiet_driver(Effects(zro_supply_dps_per_v=2.0), scenario)
    first, *_, last = readings(driver, 10, period_s=0.01)
    assert first.rate_code == ZERO_RATE_CODE
    # -0.5 V x 2 deg/s/V = -1 deg/s = -12.8 LSB.
    assert last.rate_code == round(ZERO_RATE_CODE - LSB_PER_DPS)


def test_acceleration_seen_through_the_driver():
    flat = quiet_driver(Effects(acceleration_dps_per_m_s2=(0.0, 0.0, 0.5)))
    assert flat.read().rate_code == round(ZERO_RATE_CODE + 0.5 * GRAVITY_M_S2 * LSB_PER_DPS)


def test_thermal_lag_seen_through_the_driver():
    # 1 C/s ramp from 25 C, tau = 2 s: after 10 s the sensor reads about 2 C low.
    scenario = Scenario(thermal=ThermalProfile(times_s=(0.0, 100.0),
                                               temperatures_c=(25.0, 125.0)))
    lagging = quiet_driver(Effects(thermal_lag_s=2.0), scenario)
    prompt = quiet_driver(Effects(), scenario)
    lag_code = readings(lagging, 1000, period_s=0.01)[-1].temperature_code
    prompt_code = readings(prompt, 1000, period_s=0.01)[-1].temperature_code
    # 10 mV/K = 6.4 LSB/K, so 2 C is 12.8 LSB.
    assert prompt_code - lag_code == pytest.approx(12.8, abs=1.0)


@pytest.mark.parametrize('times_s, temperatures_c', [
    ((0.0,), (25.0,)), ((0.0,), (-40,)), ((0.0, 10.0, 10.0, 30.0), (25.0, 85.0, -40.0, 0.1))])
def test_profiles_give_what_numpy_interpolation_gives_bit_for_bit(times_s, temperatures_c):
    # The ends and constant profiles skip numpy (per-sample cost): same values, as floats.
    profile = ThermalProfile(times_s=times_s, temperatures_c=temperatures_c)
    for t in (-1.0, 0.0, 1e-9, 5.0, 10.0, 20.0, 30.0, 30.0 + 1e-9, 1e6, math.inf, -math.inf):
        got = profile.chamber_c(t)
        assert type(got) is float
        assert got == float(np.interp(t, times_s, temperatures_c)), t
