"""Translation between ROS messages and the arrays the core works on."""

import math

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
import numpy as np
from sensor_msgs.msg import BatteryState, Imu, Temperature
from std_msgs.msg import MultiArrayDimension, UInt8MultiArray

from .service_window import Outcome
from ..core.node_models import AXIS_NAMES
from ..parameters.state_file import StateFileError, write_state
from ..recordings.eeprom_multiarray import eeprom_multiarray_from_images

NAN = float('nan')


def stamp_to_ns(stamp: Time) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def ns_to_stamp(stamp_ns: int) -> Time:
    return Time(sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000))


def axis_indices(axes) -> tuple:
    """Map axis names ('x', 'y', 'z') to Imu vector indices."""
    return tuple(AXIS_NAMES.index(name) for name in axes)


def rate_covariance(indices, noise_rad_s: float) -> list:
    """Return the diagonal covariance: variance on measured axes, all 0 (unknown) without noise."""
    return diagonal_covariance(indices, [noise_rad_s ** 2] * len(indices))


def diagonal_covariance(indices, variances) -> list:
    """Return the 3 x 3 covariance, row by row, with ``variances`` on the measured axes."""
    covariance = [0.0] * 9
    for index, variance in zip(indices, variances):
        covariance[4 * index] = variance
    return covariance


def imu_message(stamp: Time, frame_id: str, indices, rate_rad_s,
                covariance: list, acceleration_m_s2=None,
                acceleration_covariance: list = None) -> Imu:
    """
    Build an Imu carrying angular rate (REP-145: unreported fields flagged with -1).

    Axes the sensor does not measure are NaN: a number there would be a silent lie.
    Without ``acceleration_m_s2`` (x, y, z) the linear acceleration is flagged
    unreported; with it, ``acceleration_covariance`` goes along.
    """
    msg = Imu()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.orientation_covariance[0] = -1.0
    if acceleration_m_s2 is None:
        msg.linear_acceleration_covariance[0] = -1.0
    else:
        msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = \
            (float(v) for v in acceleration_m_s2)
        msg.linear_acceleration_covariance = acceleration_covariance
    return set_rates(msg, indices, rate_rad_s, covariance)


def set_rates(msg: Imu, indices, rate_rad_s, covariance: list) -> Imu:
    """Write angular rate and its covariance into ``msg`` (NaN on unmeasured axes); return it."""
    vector = [NAN, NAN, NAN]
    for index, value in zip(indices, rate_rad_s):
        vector[index] = float(value)
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = vector
    msg.angular_velocity_covariance = covariance
    return msg


def acceleration_covariance(noise_m_s2: float) -> list:
    """Return the diagonal covariance of a 3-axis accelerometer (all 0 = unknown)."""
    return rate_covariance((0, 1, 2), noise_m_s2)


def imu_rates(msg: Imu, indices) -> list:
    vector = (msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z)
    return [vector[i] for i in indices]


def temperature_message(stamp: Time, frame_id: str, temperature_c: float,
                        variance: float = 0.0) -> Temperature:
    msg = Temperature()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.temperature = float(temperature_c)
    msg.variance = float(variance)
    return msg


def supply_voltage_message(stamp: Time, frame_id: str, voltage_v: float) -> BatteryState:
    """Give a BatteryState carrying a measured supply voltage; unmeasured fields NaN."""
    msg = BatteryState()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.voltage = float(voltage_v)
    msg.temperature = msg.current = msg.charge = msg.capacity = NAN
    msg.design_capacity = msg.percentage = NAN
    msg.present = True
    return msg


def eeprom_message(images) -> UInt8MultiArray:
    """Pack all chips' EEPROM images: dimension 'axis' x dimension 'byte'."""
    dims, data = eeprom_multiarray_from_images(images)
    msg = UInt8MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)
                      for label, size, stride in dims]
    msg.data = data
    return msg


def diagnostic_status(name: str, hardware_id: str, level: bytes, message: str,
                      values: dict) -> DiagnosticStatus:
    """Build a status; ``level`` is DiagnosticStatus.OK, WARN, ERROR or STALE."""
    status = DiagnosticStatus(name=name, hardware_id=hardware_id, message=message, level=level)
    status.values = [KeyValue(key=key, value=_format(value)) for key, value in values.items()]
    return status


def _format(value) -> str:
    if isinstance(value, float):
        return 'nan' if math.isnan(value) else f'{value:.6g}'
    if isinstance(value, (list, tuple, np.ndarray)):
        return '[' + ', '.join(_format(float(v)) if isinstance(v, (float, np.floating))
                               else str(v) for v in value) + ']'
    return str(value)


def saved_reply(path: str, state: dict, text: str) -> Outcome:
    """Save ``state`` at ``path``; give the outcome: ``text`` and where it went, or why not."""
    try:
        write_state(path, state)
    except StateFileError as err:
        return Outcome(False, f'applied but not saved: {text}; {err}')
    return Outcome(True, f'{text}; saved to {path}')


def answer_trigger(logger, response, outcome: Outcome, what: str):
    """Put a calibration call's outcome in its Trigger response and the log; give it."""
    response.success, response.message = outcome.success, outcome.message
    # rclpy refuses two severities from one call site: one line per severity.
    if outcome.success:
        logger.info(f'{what}: {outcome.message}')
    else:
        logger.warn(f'{what}: {outcome.message}')
    return response
