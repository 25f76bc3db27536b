"""Start-up: each node says in one line what it runs and waits for; WARNs for what never comes."""

from mlx_tempcomp.core.effects import AxisTerms, EffectModel
from mlx_tempcomp.parameters.files import effect_parameters
import pytest
from ros_harness import first_line_with, start_in_namespace

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0
SUPPLY_MODEL = effect_parameters(EffectModel(
    (AxisTerms(bias=(0.01, 2e-3), supply_voltage=(4e-3,)),), supply_reference_v=5.0), ('z',))


def flat(parameters: dict, prefix: str = '') -> dict:
    """Flatten nested parameters into dotted names."""
    out = {}
    for key, value in parameters.items():
        if isinstance(value, dict):
            out.update(flat(value, f'{prefix}{key}.'))
        else:
            out[prefix + key] = value
    return out


def test_start_up_summaries_and_a_warn_for_each_input_that_never_comes(launcher, probe,
                                                                       tmp_path):
    # An eeprom model fed by an ADIS16130 (no EEPROM topic), a supply-voltage model with no
    # monitor, and a compensation node without any driver.
    adis = start_in_namespace(launcher, 'driver_node', 'adis', 'driver_node',
                              {'device': 'adis16130'}, tmp_path)
    eeprom = start_in_namespace(launcher, 'compensation_node', 'adis', 'compensation_node',
                                {'model': 'eeprom'}, tmp_path)
    start_in_namespace(launcher, 'driver_node', 'mlx', 'driver_node', {}, tmp_path)
    supply = start_in_namespace(launcher, 'compensation_node', 'mlx', 'compensation_node',
                                flat(SUPPLY_MODEL), tmp_path)
    alone = start_in_namespace(launcher, 'compensation_node', 'alone', 'compensation_node',
                               {'model': 'polynomial', 'polynomial.bias.z': [0.0]}, tmp_path)
    expected = {
        eeprom: 'the eeprom model waits for the factory tables on imu/eeprom, which only an '
                'MLX90609 driver (device: mlx90609) or a bag holding them sends; with an '
                'ADIS16130, an MPU-6000 or another driver choose another model (polynomial, '
                'linear_btc, effects or chain, from mlx-tempcomp fit); until they come, after '
                'eeprom.wait_s, the node runs the rate only',
        supply: 'the effects model has supply_voltage terms and waits for a voltage on '
                'imu/supply_voltage (sensor_msgs/BatteryState)',
        alone: 'no raw samples yet: start a driver_node',
    }
    for process, text in expected.items():
        probe.spin_until(lambda: text in process.output(), TIMEOUT_S, text, launcher)
        assert first_line_with(process.output(), text).startswith('[WARN]')

    assert ("device adis16130, source simulated, axes ['z']: simulated ADIS16130"
            in adis.output()), adis.output()
    assert ('publishes /adis/imu/data_raw, /adis/imu/temperature_raw, /diagnostics, '
            '/adis/imu/bias_procedure/status; services /adis/imu/run_bias_procedure'
            in adis.output()), adis.output()
    learned = tmp_path / 'compensation_node_learned.yaml'
    assert (f"model eeprom on axes ['z'], bias tracking on, field learning on "
            f'(imu/save_learned_model writes {learned}); waits for /adis/imu/eeprom, '
            '/adis/imu/data_raw, /adis/imu/temperature_raw; temperature paired by hold '
            'within 2 s, the rate only without one 5 s after the first sample; the factory '
            'tables waited for 5 s, then the rate only until they come (only an MLX90609 '
            'driver sends them); publishes /adis/imu/data, '
            '/adis/imu/temperature, /diagnostics, /adis/imu/gyro_bias, '
            '/adis/imu/gyro_bias/status (covariance: rate noise + tracked offset variance); '
            f'state file {tmp_path / "adis_compensation_node"}: nothing saved yet'
            in eeprom.output()), eeprom.output()
    assert '/mlx/imu/supply_voltage' in first_line_with(supply.output(), 'model effects on')
