"""
What the compensation node reports: its diagnostic status, and what it still waits for.

`compensation_status` gives the level, text and values of its ``/diagnostics``
status from the node's parts: its settings, the model, the factory
tables, the inputs (`CompensationInputs`: what arrived when, what they could
not pair), what it compensated (`OutputCounts`), the ZRO recalibration
(`ZroRecalibration`) and the bias tracking (`CompensationTracking.status_values`).
`missing_inputs` says, for the start-up WARN, which input has not come and
what to set.
"""

from typing import Optional

from diagnostic_msgs.msg import DiagnosticStatus

from .inputs import CompensationInputs
from .outputs import CompensationOutputs
from .zro_recalibration import ZroRecalibration
from ...parameters.compensation import CompensationSettings


def _age(now: float, then: Optional[float]) -> float:
    return float('nan') if then is None else now - then


def missing_inputs(model_name: str, tables: bool, inputs: CompensationInputs) -> list:
    """Say what has not come yet and what to set: raw samples, factory tables, a voltage."""
    missing = []
    topics = ', '.join(inputs.temperature_topics.values())
    if inputs.last_imu is None:
        missing.append('no raw samples yet: start a driver_node (same namespace and '
                       'ROS_DOMAIN_ID) publishing imu/data_raw'
                       + (f' and {topics}' if topics else '') + ", or remap your driver's "
                       'topics to them (-r imu/data_raw:=<its Imu topic>)')
    elif inputs.waiting_for_temperature:
        missing.append(f'Imu samples arrive but no temperature on {topics}: remap your '
                       "driver's Temperature topic to it, or set temperature.pairing none if "
                       'it sends none')
    if model_name == 'eeprom' and not tables:
        missing.append('the eeprom model waits for the factory tables on imu/eeprom, which '
                       'only an MLX90609 driver (device: mlx90609) or a bag holding them '
                       'sends; with an ADIS16130, an MPU-6000 or another driver choose '
                       'another model (polynomial, linear_btc, effects or chain, from '
                       'mlx-tempcomp fit); until they come, after eeprom.wait_s, the node '
                       'runs the rate only')
    if inputs.waiting_for_supply:
        missing.append(f'the {model_name} model has supply_voltage terms and waits for a '
                       'voltage on imu/supply_voltage (sensor_msgs/BatteryState): remap '
                       "your supply monitor's topic to it, or set "
                       'simulation.supply_monitor_hz on a simulated MLX90609 driver')
    return missing


def compensation_status(*, settings: CompensationSettings, model, sensor, eeprom_error: str,
                        alone: str, now: float, inputs: CompensationInputs,
                        outputs: CompensationOutputs, recalibration: ZroRecalibration,
                        tracking: dict) -> tuple:
    """
    Give (level, text, values) of the node's status.

    ``settings`` are the node's, ``sensor`` the factory tables (None
    before the EEPROM message), ``alone`` why the node runs the rate only ('' when
    the model runs), ``now`` the monotonic time the input ages count to;
    ``tracking`` the bias tracking's values.
    """
    model_name = settings.model
    imu_age_s = _age(now, inputs.last_imu)
    temperature_age_s = _age(now, inputs.last_temperature)
    model_error = outputs.model_error
    recal = recalibration.last
    diagnostic_values = {
        'model': model_name,
        'fingerprint': '' if model is None else model.fingerprint(),
        'zro_offset': [] if model is None else list(model.zro_offset),
        'offset_unit': '' if model is None else model.offset_unit,
        'samples_out': outputs.samples_out, 'samples_waiting': inputs.samples_waiting,
        'blocks': outputs.blocks, 'largest_block': outputs.largest_block,
        'unpaired_dropped': inputs.unpaired_dropped,
        'compensation': f'rate only: {alone}' if alone else 'model',
        'temperature_pairing': settings.temperature.pairing,
        'no_temperature_samples': inputs.no_temperature_samples,
        'imu_age_s': imu_age_s, 'temperature_age_s': temperature_age_s,
        'temperature_stamp_age_s': inputs.temperature_stamp_age_ns / 1e9,
        'samples_waiting_for_temperature': inputs.held_back[0],
        'temperature_clamped_samples': outputs.clamped_samples,
        'model_error_temperatures': 0 if model_error is None else
        len(model_error.temperature_c),
        # The covariance judged at rest: still windows' mean rate over its std (1: true).
        'still_windows_checked': outputs.still_windows.windows,
        'still_normalised_error_rms': outputs.still_windows.rms(),
        'no_acceleration_samples': inputs.no_acceleration_samples,
        'no_supply_voltage_samples': inputs.no_supply_samples,
        'input_age_s': imu_age_s,
        'last_recalibration_time': recal.get('time', 'never'),
        'last_recalibration_offset_rad_s': recal.get('zro_offset_rad_s', []),
        'last_recalibration_temperature_c': recal.get('temperature_c', float('nan')),
        'state_file': recalibration.path,
        'eeprom_outvoted_bits': 0 if sensor is None else sensor.outvoted_bits,
        **tracking,
    }
    level, text = _level_and_text(settings, model, eeprom_error, alone, inputs, outputs, tracking,
                                  imu_age_s, temperature_age_s)
    return level, text, diagnostic_values


def _level_and_text(settings, model, eeprom_error, alone, inputs, outputs, tracking,
                    imu_age_s, temperature_age_s) -> tuple:
    """Give the status's level and text: the worst of what the node sees, first."""
    model_name = settings.model
    stale_s = settings.stale_timeout_s
    max_age_s = settings.temperature.max_age_s
    topics = ', '.join(inputs.temperature_topics.values())
    if not imu_age_s <= stale_s:   # NaN before the first too
        if temperature_age_s <= stale_s:
            since = 'yet' if inputs.last_imu is None else f'for {imu_age_s:.3g} s'
            return (DiagnosticStatus.ERROR, f'stale input: no Imu samples on imu/data_raw '
                    f'{since} while the temperature arrives')
        return DiagnosticStatus.ERROR, 'stale input: no raw samples'
    if inputs.no_temperature_recent:
        return (DiagnosticStatus.ERROR,
                f'Imu samples without a temperature within temperature.max_age_s '
                f'({max_age_s:g} s) on {topics} (last one '
                f'{temperature_age_s:.3g} s ago): {inputs.no_temperature_samples} samples not '
                'compensated')
    if eeprom_error:
        level, text = DiagnosticStatus.ERROR, f'EEPROM unusable: {eeprom_error}'
    elif inputs.no_acceleration_recent:
        level, text = (DiagnosticStatus.ERROR,
                       f'the {model_name} model needs acceleration but Imu '
                       'messages carry none (linear_acceleration_covariance[0] = -1): '
                       f'{inputs.no_acceleration_samples} samples not compensated')
    elif inputs.no_supply_recent:
        level, text = (DiagnosticStatus.ERROR,
                       f'the {model_name} model needs the supply voltage but '
                       'imu/supply_voltage gave none within supply_voltage.max_age_s '
                       f'({settings.supply_voltage.max_age_s:g} s) of the samples: '
                       f'{inputs.no_supply_samples} samples not compensated')
    elif inputs.held_back[1] > max_age_s:
        waiting, waited_s = inputs.held_back
        level, text = (DiagnosticStatus.WARN,
                       f'{waiting} Imu samples waiting for the temperature of their own stamp '
                       f'on {topics}, the oldest {waited_s:.3g} s (stamps): it comes late')
    elif alone:
        level, text = (DiagnosticStatus.WARN,
                       f'rate only: {alone}; the raw rate less the tracked offset, no '
                       'temperature model')
    elif inputs.waiting_for_temperature:
        level, text = (DiagnosticStatus.WARN,
                       f'waiting for a first temperature on {topics}: the rate only after '
                       f'temperature.wait_s ({settings.temperature.wait_s:g} s)')
    elif model is None:
        level, text = (DiagnosticStatus.WARN,
                       'waiting for the EEPROM tables: the rate only after eeprom.wait_s '
                       f'({settings.eeprom_wait_s:g} s)')
    elif inputs.waiting_for_supply:
        level, text = DiagnosticStatus.WARN, 'waiting for a supply voltage on imu/supply_voltage'
    elif outputs.clamped_recent:
        level, text = DiagnosticStatus.WARN, 'temperature outside the calibrated range: clamped'
    elif tracking.get('tracking_state_error'):
        level, text = (DiagnosticStatus.WARN,
                       f'bias tracking state not saved: {tracking["tracking_state_error"]}')
    else:
        level, text = DiagnosticStatus.OK, f'compensating ({model_name})'
    return level, text
