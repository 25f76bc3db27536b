"""
The driver node's parameters: its specs per device and source, and the settings they make.

`DEVICES` names the parts the driver reads (a test holds it equal to the
driver's ``STREAMS``), `I2C_DEVICES` those of them that also speak I2C;
`DRIVER_SPECS` are the parameters both nodes share (`specs.COMMON_SPECS`),
then the driver's: the source, SPI, I2C, bag replay, the simulated part, and
one group per device (``adis16130.*``, ``mpu6000.*``). `bus_of` gives the bus
a part is read over and refuses I2C for a part that has none.

`driver_settings` turns the values into `DriverSettings`, frozen and typed, one
section per group of parameters, checking what no descriptor can say: how the
parameters go together (a part on the bus it has, one axis for the ADIS16130, the
chip selects the axes need, a bag source with its path, the supply monitor on the
simulated MLX90609 only); `ParameterError` names the parameter. What needs the part
itself stays with its stream (its natural rate against ``publish_rate_hz``, the
MPU's register ranges and addresses, which are the hardware layer's).
"""

from dataclasses import dataclass, fields

from .specs import (axes_of, COMMON_SPECS, NoDefault, ParameterError, sensor_of, SensorSettings,
                    Spec)
from ..core.procedures import ProcedureSettings, short_window
from ..simulation.mlx90609 import Fault
from ..simulation.physics import Effects

DEVICES = ('mlx90609', 'adis16130', 'mpu6000')
# The parts with an I2C interface; the others speak SPI only.
I2C_DEVICES = ('mpu6000',)

DRIVER_SPECS = COMMON_SPECS + (
    Spec('device', 'mlx90609', 'sensor read by the simulated, spidev and i2c sources',
         read_only=True, choices=DEVICES),
    Spec('source', 'simulated', 'where raw data comes from: simulated, spidev (Linux SPI), i2c '
         '(Linux i2c-dev; the mpu6000 family only) or bag', read_only=True,
         choices=('simulated', 'spidev', 'i2c', 'bag')),
    Spec('frame_id', 'imu_link', 'frame_id of published messages (REP-145)'),
    Spec('publish_rate_hz', 100.0, 'publish rate in Hz (simulated time for the simulated '
         'source); each message is the mean of the device samples of its interval',
         read_only=True, low=0.1, high=10000.0),
    Spec('sample_rate_hz', 0.0, 'device sample rate in Hz, at least publish_rate_hz; 0 = the '
         "part's natural rate (MLX90609 1000, UNCONFIRMED; ADIS16130 5700; MPU-6000 its gyro "
         'output rate over 1 + SMPLRT_DIV)', read_only=True, low=0.0, high=100000.0),
    Spec('oversample', 1, 'conversions averaged per device sample', read_only=True,
         low=1, high=256),
    Spec('spi.bus', 0, 'spidev bus number', read_only=True, low=0, high=255),
    Spec('spi.chip_selects', [0], 'spidev chip select per axis, same order as axes',
         read_only=True),
    Spec('spi.speed_hz', 0,
         'SPI clock in Hz; 0 = the device default (MLX90609 500 kHz, its maximum UNCONFIRMED; '
         'ADIS16130 1 MHz; MPU-6000/6500 1 MHz, the limit for configuration registers)',
         read_only=True, low=0, high=20000000),
    Spec('spi.mode', 3, 'SPI mode (0 or 3 work: data latched on the rising edge)',
         read_only=True, low=0, high=3),
    Spec('i2c.bus', 1, 'i2c-dev bus number (/dev/i2c-<bus>); the adapter sets the clock '
         '(device tree), at most 400 kHz for the MPU', read_only=True, low=0, high=255),
    Spec('i2c.address', 0x68, '7-bit I2C address of the part; the MPU: 0x68 (104) with AD0 '
         'low, 0x69 (105) with AD0 high', read_only=True, low=0x08, high=0x77),
    Spec('bag.path', '', 'rosbag2 folder (sqlite3 or mcap) to replay', read_only=True),
    Spec('bag.rate_factor', 1.0,
         'replay speed: 1 = recorded rate, 2 = twice as fast, 0 = as fast as the consumer '
         'takes it (paced by bag.pace_topic)',
         read_only=True, low=0.0, high=1000.0),
    Spec('bag.pace_topic', 'imu/data',
         'at rate factor 0: keep at most 100 samples ahead of the stamps seen here',
         read_only=True),
    Spec('bag.pace_timeout_s', 1.0,
         'at rate factor 0: after this long without progress on bag.pace_topic the replay '
         'goes on anyway (a replay nobody consumes still ends)',
         read_only=True, low=0.001, high=3600.0),
    Spec('bag.on_end', 'stop', 'at the end of the bag: stop (log a summary, exit 0), loop '
         '(start over, stamps shifted to keep increasing) or hold (stay up, publish nothing)',
         read_only=True, choices=('stop', 'loop', 'hold')),
    Spec('bag.imu_topic', '/imu/data_raw', 'Imu topic in the bag', read_only=True),
    Spec('bag.temperature_topic', '/imu/temperature_raw', 'Temperature topic in the bag',
         read_only=True),
    Spec('bag.eeprom_topic', '/imu/eeprom', 'EEPROM topic in the bag', read_only=True),
    Spec('bag.supply_voltage_topic', '/imu/supply_voltage',
         'supply-voltage topic in the bag (sensor_msgs/BatteryState), replayed as '
         'imu/supply_voltage when the bag has it', read_only=True),
    Spec('bag.temperature_2_topic', '',
         "second-temperature topic in the bag, replayed as imu/temperature_2_raw ('' = none)",
         read_only=True),
    Spec('simulation.bus', 'spi', 'bus the simulated part is read over: spi (frames) or i2c '
         '(block reads at i2c.address; the mpu6000 family only)', read_only=True,
         choices=('spi', 'i2c')),
    Spec('simulation.seed', 0, 'seed of the simulated chips and their noise', read_only=True,
         low=0, high=2**31 - 1),
    Spec('simulation.real_time_factor', 1.0,
         'simulated seconds per wall second (10 = ten times faster than real time)',
         read_only=True, low=0.001, high=10000.0),
    Spec('simulation.lossless', False,
         'read every sample: a driver that falls behind lets the simulated clock lag wall '
         'time instead of skipping samples as missed reads (for tests)', read_only=True),
    Spec('simulation.wait_for_subscriber', False,
         'hold the simulated clock at 0 until imu/data_raw has a subscriber (or a '
         'compensation node in the same process), so a late listener misses nothing',
         read_only=True),
    Spec('simulation.eeprom_version', 2, 'EEPROM VERSION the simulated factory writes',
         read_only=True, low=0, high=255),
    Spec('simulation.start_temperature_c', 25.0, 'chamber temperature at start',
         read_only=True, low=-60.0, high=125.0),
    Spec('simulation.cycle_temperatures_c', NoDefault('double_array'),
         'chamber temperatures to ramp through in turn (empty: constant)', read_only=True),
    Spec('simulation.ramp_c_per_min', 2.0, 'chamber ramp rate', read_only=True,
         low=0.001, high=1000.0),
    Spec('simulation.hold_s', 0.0, 'soak at each cycle temperature', read_only=True,
         low=0.0, high=1e6),
    Spec('simulation.die_time_constant_s', 0.0, 'die follows the chamber with this lag',
         read_only=True, low=0.0, high=1e5),
    Spec('simulation.rate_dps', [0.0], 'true rate in deg/s, one value or one per axis',
         read_only=True),
    Spec('simulation.supply_v', 5.0,
         'supply voltage (settable at runtime on the MLX90609: a step from the next sample)',
         low=0.0, high=10.0),
    Spec('simulation.supply_monitor_hz', 0.0,
         'MLX90609: publish the simulated supply on imu/supply_voltage (BatteryState) at this '
         'rate, on stamps of its own, as a board supply monitor would (0 = none)',
         read_only=True, low=0.0, high=1000.0),
    Spec('simulation.thermal_lag_s', 0.0, 'effect: temperature sensor lags the die',
         read_only=True, low=0.0, high=1e5),
    Spec('simulation.hysteresis_dps', 0.0, 'effect: ZRO heating/cooling branch difference',
         read_only=True, low=-100.0, high=100.0),
    Spec('simulation.zro_supply_dps_per_v', 0.0, 'effect: ZRO shift per volt off 5 V',
         read_only=True, low=-1000.0, high=1000.0),
    Spec('simulation.fault', 'none',
         'SPI fault of the simulated chips (settable at runtime; adis16130 and mpu6000: none, '
         'silent_high, silent_low)', choices=tuple(f.value for f in Fault)),
    Spec('simulation.bias_dps', 0.0, 'adis16130: bias at 25 C in deg/s', read_only=True,
         low=-1000.0, high=1000.0),
    Spec('simulation.bias_dps_per_c', 0.0,
         'adis16130: bias temperature slope in deg/s/C (mpu6000: drawn from the seed)',
         read_only=True, low=-100.0, high=100.0),
    Spec('adis16130.resolution_bits', 24, 'conversion resolution, 24 or 16 (MODE b1)',
         read_only=True, low=16, high=24),
    Spec('adis16130.verify_registers', True,
         'read the start-up registers back (read-back UNCONFIRMED on real parts)',
         read_only=True),
    Spec('adis16130.bias_procedure.average_s', 10.0, 'window of each point (the note: 10 s)',
         low=0.01, high=3600.0),
    Spec('adis16130.bias_procedure.self_heat_s', 600.0,
         'wait between the points while the part warms itself (the note: 600 s)',
         low=0.0, high=1e5),
    Spec('adis16130.bias_procedure.settle_s', 2400.0,
         'wait before the PBC window, the rest record included (the note: 2400 s)',
         low=0.0, high=1e5),
    Spec('adis16130.bias_procedure.pbc_s', 150.0,
         'PBC window (the note: 150 s); 0 = the averaging time the rest record advises',
         low=0.0, high=1e5),
    Spec('adis16130.bias_procedure.allan_record_s', 1200.0,
         'rest record at the end of the settle wait for the Allan deviation (0 = none: no '
         'noise figures, motion check against rate_noise_rad_s)', low=0.0, high=1e5),
    Spec('adis16130.bias_procedure.min_temperature_change_c', 0.5,
         'smallest T2 - T1 a BTC is computed from', low=0.001, high=100.0),
    Spec('adis16130.bias_procedure.output_file', '',
         "linear_btc parameter file ('' = $ROS_HOME/mlx_tempcomp/<namespace>/<node "
         'name>_linear_btc.yaml, ROS_HOME defaulting to ~/.ros)'),
    Spec('adis16130.bias_procedure.node_name', 'compensation_node',
         'node section of the parameter file'),
    Spec('mpu6000.variant', 'mpu6000', 'part: MPU-6000, MPU-6050 (I2C only, the registers of '
         'the MPU-6000) or MPU-6500', read_only=True, choices=('mpu6000', 'mpu6050', 'mpu6500')),
    Spec('mpu6000.gyro_full_scale_dps', 250, 'gyro range: 250, 500, 1000 or 2000 deg/s',
         read_only=True, low=250, high=2000),
    Spec('mpu6000.accel_full_scale_g', 2, 'accelerometer range: 2, 4, 8 or 16 g',
         read_only=True, low=2, high=16),
    Spec('mpu6000.dlpf_config', 3, 'DLPF_CFG (CONFIG bits 2..0)', read_only=True, low=0,
         high=6),
    Spec('mpu6000.sample_rate_divider', 0, 'SMPLRT_DIV', read_only=True, low=0, high=255),
    Spec('mpu6000.accel_noise_m_s2', 0.049,
         '1-sigma accelerometer noise of one sample in m/s^2 (datasheet 400 ug/sqrt(Hz) at '
         '100 Hz: 0.005 g); sets the linear acceleration covariance (0 = unknown)',
         low=0.0, high=100.0),
    Spec('mpu6000.offsets_file', '',
         "offset register state YAML ('' = $ROS_HOME/mlx_tempcomp/<namespace>/<node "
         'name>_offsets.yaml, ROS_HOME defaulting to ~/.ros)',
         read_only=True),
    Spec('mpu6000.calibration.duration_s', 1.0,
         'averaging window of imu/calibrate_offsets (sensor time; the note: 200 samples)',
         low=0.01, high=3600.0),
    Spec('mpu6000.calibration.noise_multiple', 3.0,
         'a gyro rate spread above this x rate_noise_rad_s means the board moves',
         low=0.1, high=1000.0),
    Spec('mpu6000.offset_model_file', '',
         'parameter file of a polynomial bias model of gyro x, y, z (mlx-tempcomp fit): '
         "refresh the gyro offset registers from it as the temperature moves ('' = off)",
         read_only=True),
    Spec('mpu6000.offset_model_node', 'compensation_node',
         'node section of mpu6000.offset_model_file', read_only=True),
    Spec('mpu6000.offset_refresh_c', 0.5,
         'rewrite the gyro offset registers when the temperature moved this much since the '
         'last write', read_only=True, low=0.001, high=100.0),
)


def bus_of(values: dict) -> str:
    """Give the bus the part is read over, 'spi' or 'i2c' (the bag source: 'spi', unused)."""
    name = {'i2c': 'source', 'simulated': 'simulation.bus'}.get(values['source'])
    if name is None or values[name] != 'i2c':
        return 'spi'
    if values['device'] not in I2C_DEVICES:
        msg = (f'invalid parameter {name}: the {values["device"]} speaks SPI only; i2c is for '
               f'the {", ".join(I2C_DEVICES)}')
        raise ParameterError(msg)
    return 'i2c'


def effects_of(values: dict) -> Effects:
    return Effects(thermal_lag_s=values['simulation.thermal_lag_s'],
                   hysteresis_dps=values['simulation.hysteresis_dps'],
                   zro_supply_dps_per_v=values['simulation.zro_supply_dps_per_v'])


@dataclass(frozen=True)
class SpiSettings:
    """``spi.*``: the spidev bus, a chip select per part, the clock (0 = the part's) and mode."""

    bus: int
    chip_selects: tuple
    speed_hz: int
    mode: int


@dataclass(frozen=True)
class I2cSettings:
    """``i2c.*``: the i2c-dev bus and the part's 7-bit address."""

    bus: int
    address: int


@dataclass(frozen=True)
class BagSettings:
    """``bag.*``: the bag replayed, how fast, what at its end, and its topics."""

    path: str
    rate_factor: float
    pace_topic: str
    pace_timeout_s: float
    on_end: str
    imu_topic: str
    temperature_topic: str
    eeprom_topic: str
    supply_voltage_topic: str
    temperature_2_topic: str     # '' = none


@dataclass(frozen=True)
class SimulationSettings:
    """``simulation.*``: the simulated part, its clock, chamber, truth, effects and fault."""

    bus: str
    seed: int
    real_time_factor: float
    lossless: bool
    wait_for_subscriber: bool
    eeprom_version: int
    start_temperature_c: float
    cycle_temperatures_c: tuple
    ramp_c_per_min: float
    hold_s: float
    die_time_constant_s: float
    rate_dps: tuple
    supply_v: float
    supply_monitor_hz: float
    effects: Effects
    fault: str
    bias_dps: float
    bias_dps_per_c: float


@dataclass(frozen=True)
class BiasProcedureSettings:
    """``adis16130.bias_procedure.*``: its windows and waits, and the file it writes."""

    average_s: float
    self_heat_s: float
    settle_s: float
    pbc_s: float                 # 0 = the averaging time the rest record advises
    allan_record_s: float
    min_temperature_change_c: float
    output_file: str             # '' = under ROS_HOME
    node_name: str


@dataclass(frozen=True)
class Adis16130Settings:
    """``adis16130.*``: the conversion, the register read-back and the bias procedure."""

    resolution_bits: int
    verify_registers: bool
    bias_procedure: BiasProcedureSettings


@dataclass(frozen=True)
class Mpu6000Settings:
    """``mpu6000.*``: the part, its ranges and filter, its offsets and their refresh."""

    variant: str
    gyro_full_scale_dps: int
    accel_full_scale_g: int
    dlpf_config: int
    sample_rate_divider: int
    accel_noise_m_s2: float
    offsets_file: str            # '' = under ROS_HOME
    calibration_duration_s: float
    calibration_noise_multiple: float
    offset_model_file: str       # '' = no refresh
    offset_model_node: str
    offset_refresh_c: float


@dataclass(frozen=True)
class DriverSettings:
    """The driver node's parameters, checked; one section per group."""

    device: str
    source: str
    axes: tuple
    bus: str                     # what the part is read over: 'spi' or 'i2c' (`bus_of`)
    frame_id: str
    rate_noise_rad_s: float
    publish_rate_hz: float
    sample_rate_hz: float        # 0 = the part's natural rate
    oversample: int
    sensor: SensorSettings
    spi: SpiSettings
    i2c: I2cSettings
    bag: BagSettings
    simulation: SimulationSettings
    adis16130: Adis16130Settings
    mpu6000: Mpu6000Settings

    @property
    def simulated(self) -> bool:
        return self.source == 'simulated'

    @property
    def simulated_mlx90609(self) -> bool:
        """Tell whether the simulated MLX90609 runs: the one with a supply to set and monitor."""
        return self.device == 'mlx90609' and self.simulated


def _section(cls, values: dict, prefix: str, **given):
    """Give ``cls`` with each field the value of ``prefix`` + its name, but those ``given``."""
    names = [field.name for field in fields(cls) if field.name not in given]
    return cls(**{name: _plain(values[prefix + name]) for name in names}, **given)


def _plain(value):
    """Give a list value as a tuple (frozen settings), any other as it is."""
    return tuple(value) if isinstance(value, list) else value


def driver_settings(values: dict) -> DriverSettings:
    """
    Give the driver's settings of its parameter values; `ParameterError` names what is wrong.

    The values are those `ros.declare.declare` gives (types, ranges and choices
    checked); here how they go together.
    """
    axes = axes_of(values)
    sensor = sensor_of(values)
    bus = bus_of(values)
    simulation = _section(SimulationSettings, values, 'simulation.', effects=effects_of(values))
    mpu6000 = _section(Mpu6000Settings, values, 'mpu6000.',
                       calibration_duration_s=values['mpu6000.calibration.duration_s'],
                       calibration_noise_multiple=values['mpu6000.calibration.noise_multiple'])
    settings = DriverSettings(
        device=values['device'], source=values['source'], axes=axes, bus=bus,
        frame_id=values['frame_id'], rate_noise_rad_s=values['rate_noise_rad_s'],
        publish_rate_hz=values['publish_rate_hz'], sample_rate_hz=values['sample_rate_hz'],
        oversample=values['oversample'], sensor=sensor, spi=_section(SpiSettings, values, 'spi.'),
        i2c=_section(I2cSettings, values, 'i2c.'), bag=_section(BagSettings, values, 'bag.'),
        simulation=simulation,
        adis16130=_section(Adis16130Settings, values, 'adis16130.', bias_procedure=_section(
            BiasProcedureSettings, values, 'adis16130.bias_procedure.')),
        mpu6000=mpu6000)
    _check(settings)
    return settings


def _check(settings: DriverSettings) -> None:
    """Raise `ParameterError` for parameters that do not go together; see the module notes."""
    if not settings.frame_id:
        raise ParameterError('invalid parameter frame_id: must not be empty')
    if settings.simulation.supply_monitor_hz and not settings.simulated_mlx90609:
        msg = ('invalid parameter simulation.supply_monitor_hz: the supply monitor belongs '
               'to the simulated MLX90609 (device mlx90609, source simulated); a real '
               'board monitor publishes imu/supply_voltage itself')
        raise ParameterError(msg)
    if settings.source == 'bag':
        if not settings.bag.path:
            raise ParameterError('invalid parameter bag.path: the bag source needs a path')
        return
    check_part = _PART_CHECKS.get(settings.device)
    if check_part is not None:
        check_part(settings)
    if settings.source != 'spidev':
        return
    selects = settings.spi.chip_selects
    if settings.device == 'mlx90609' and len(selects) != len(settings.axes):
        msg = (f'invalid parameter spi.chip_selects: {len(selects)} chip selects for '
               f'{len(settings.axes)} axes')
        raise ParameterError(msg)
    if settings.device != 'mlx90609' and len(selects) != 1:
        msg = (f'invalid parameter spi.chip_selects: the {settings.device} is one part on one '
               f'chip select, got {len(selects)}')
        raise ParameterError(msg)


def _check_adis16130(settings: DriverSettings) -> None:
    if len(settings.axes) != 1:
        msg = (f'invalid parameter axes: the adis16130 measures one axis, got '
               f'{list(settings.axes)}')
        raise ParameterError(msg)
    bits = settings.adis16130.resolution_bits
    if bits not in (16, 24):
        msg = f'invalid parameter adis16130.resolution_bits: 24 or 16, got {bits}'
        raise ParameterError(msg)
    rate_dps = settings.simulation.rate_dps
    if settings.simulated and len(rate_dps) != 1:
        msg = (f'invalid parameter simulation.rate_dps: the adis16130 measures one '
               f'axis, give one value, got {len(rate_dps)}')
        raise ParameterError(msg)


def _check_mpu6000(settings: DriverSettings) -> None:
    if settings.oversample != 1:
        msg = (f'invalid parameter oversample: the mpu6000 averages in its DLPF, not in '
               f'the driver; give 1, got {settings.oversample}')
        raise ParameterError(msg)
    if not settings.simulated:
        return
    simulation = settings.simulation
    if simulation.die_time_constant_s != 0.0:
        msg = ('invalid parameter simulation.die_time_constant_s: the simulated mpu6000 '
               'follows its thermal profile directly, give 0')
        raise ParameterError(msg)
    if len(simulation.rate_dps) not in (1, len(settings.axes)):
        msg = (f'invalid parameter simulation.rate_dps: one value or one per axis '
               f'({len(settings.axes)}), got {len(simulation.rate_dps)}')
        raise ParameterError(msg)


# The checks of each part's parameters (the MLX90609's chip selects are the driver's).
_PART_CHECKS = {'adis16130': _check_adis16130, 'mpu6000': _check_mpu6000}


def procedure_settings(settings: DriverSettings) -> ProcedureSettings:
    """
    Give the ADIS16130 bias procedure's settings; `ParameterError` names a window too short.

    Checked when a procedure starts: ``adis16130.bias_procedure.*`` may change at run time.
    """
    prefix = 'adis16130.bias_procedure.'
    given = settings.adis16130.bias_procedure
    rate_hz = settings.publish_rate_hz
    allan_s = given.allan_record_s
    pbc_s = given.pbc_s or None
    short = short_window(rate_hz, given.average_s, pbc_s, allan_s)
    if short is not None:
        name, seconds, why = short
        msg = f'invalid parameter {prefix}{name}: {seconds:g} s at rate_hz {rate_hz:g} {why}'
        raise ParameterError(msg)
    if pbc_s is None and allan_s == 0.0:
        msg = (f'invalid parameter {prefix}pbc_s: 0 (advised by the rest record) needs '
               f'{prefix}allan_record_s > 0')
        raise ParameterError(msg)
    return ProcedureSettings(
        average_s=given.average_s, self_heat_s=given.self_heat_s, settle_s=given.settle_s,
        pbc_s=pbc_s, allan_record_s=allan_s,
        min_temperature_change_c=given.min_temperature_change_c,
        rate_noise_rad_s=settings.rate_noise_rad_s or None)
