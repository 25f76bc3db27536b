"""
The compensation node over DDS: beyond the fitted range, and the covariance of the model error.

A probe feeds compensation_node raw pairs at chosen temperatures (reliable
streams, so every sample is compensated and counted) and reads imu/data and
/diagnostics. The model file is written as ``diagnose`` writes one: an
effects model and a ``model_error`` table.
"""

from diagnostic_msgs.msg import DiagnosticStatus
from mlx_tempcomp.core.effects import AxisTerms, EffectModel
from mlx_tempcomp.core.node_models.interface import ModelInputs
from mlx_tempcomp.core.node_models.model_error import ModelErrorTable
from mlx_tempcomp.parameters.files import (effect_parameters, model_error_parameters,
                                           parameter_file, write_parameter_file)
from mlx_tempcomp.ros import messages
import numpy as np
import pytest
from ros_harness import (by_stamp, COMPENSATION_DIAGNOSTIC, reliable, RELIABLE_RECORD_QOS,
                         status_values, UNTRACKED)
from sensor_msgs.msg import Imu, Temperature

pytestmark = pytest.mark.ros

TIMEOUT_S = 60.0
AXES = ('x', 'z')
NOISE_RAD_S = 0.004
MODEL = EffectModel(terms=(AxisTerms(bias=(1e-3, 2e-3, 5e-4)), AxisTerms(bias=(-2e-3, 1e-3))),
                    reference_temperature_c=20.0, temperature_scale_c=20.0,
                    temperature_min_c=0.0, temperature_max_c=40.0)
TABLE = ModelErrorTable((10.0, 30.0), ((1e-3, 3e-3), (2e-3, 0.0)))


def start_node(launcher, probe, tmp_path, table=TABLE) -> None:
    """Start compensation_node on MODEL (and ``table``), reliable inputs and output."""
    content = effect_parameters(MODEL, AXES)
    if table is not None:
        content.update(model_error_parameters(table, AXES))
    model_file = tmp_path / 'model.yaml'
    write_parameter_file(model_file, parameter_file('compensation_node', content))
    probe.subscribe(Imu, 'imu/data', RELIABLE_RECORD_QOS)
    probe.subscribe_diagnostics()
    # A long stale time-out: the status after the last sample says clamped, not stale.
    launcher.start('compensation_node', 'compensation_node', {
        'rate_noise_rad_s': NOISE_RAD_S, 'recalibration.state_file': str(tmp_path / 'zro.yaml'),
        'stale_timeout_s': 600.0, **UNTRACKED,
        **reliable(['imu/data_raw', 'imu/temperature_raw'], 'subscription'),
        **reliable(['imu/data'], 'publisher')},
        extra_args=['--params-file', str(model_file)], label='compensation')


class Feeder:
    """Reliable publishers of raw pairs into the node; remembers what it sent by stamp."""

    def __init__(self, probe, launcher):
        self.probe, self.launcher = probe, launcher
        self.imu = probe.node.create_publisher(Imu, 'imu/data_raw', RELIABLE_RECORD_QOS)
        self.temperature = probe.node.create_publisher(Temperature, 'imu/temperature_raw',
                                                       RELIABLE_RECORD_QOS)
        self.sent = {}   # stamp in ns -> (raw rates in rad/s, temperature in degC)
        probe.spin_until(lambda: self.imu.get_subscription_count() and
                         self.temperature.get_subscription_count() and
                         probe.node.count_publishers('imu/data'),
                         TIMEOUT_S, 'the compensation node', launcher)

    def send(self, temperatures_c) -> list:
        """Publish one pair per temperature; wait until each is compensated; give the stamps."""
        rng = np.random.default_rng(len(self.sent))
        indices = messages.axis_indices(AXES)
        stamps = []
        for temperature_c in temperatures_c:
            stamp_ns = 1_000_000_000 + len(self.sent) * 10_000_000
            stamp = messages.ns_to_stamp(stamp_ns)
            raw_rad_s = rng.normal(0.0, 0.05, len(AXES))
            self.imu.publish(messages.imu_message(stamp, 'imu_link', indices, raw_rad_s,
                                                  [0.0] * 9))
            self.temperature.publish(messages.temperature_message(stamp, 'imu_link',
                                                                  float(temperature_c)))
            self.sent[stamp_ns] = (raw_rad_s, float(temperature_c))
            stamps.append(stamp_ns)
        self.probe.spin_until(lambda: set(stamps) <= set(by_stamp(self.probe.received[
            'imu/data'])), TIMEOUT_S, f'{len(stamps)} compensated samples', self.launcher)
        return stamps

    def outputs(self, stamps) -> list:
        received = by_stamp(self.probe.received['imu/data'])
        return [received[stamp] for stamp in stamps]


def test_beyond_the_fitted_range_the_node_gives_the_edge_value_and_counts_it(
        launcher, probe, tmp_path):
    start_node(launcher, probe, tmp_path, table=None)
    feeder = Feeder(probe, launcher)
    temperatures_c = [-15.0, 0.0, 20.0, 40.0, 55.0, 90.0] * 5
    stamps = feeder.send(temperatures_c)
    indices = messages.axis_indices(AXES)
    raw = np.array([feeder.sent[s][0] for s in stamps])
    got = np.array([messages.imu_rates(msg, indices) for msg in feeder.outputs(stamps)])
    # What the model gives at the edge of its range (0 and 40 C) for the same raw rates.
    edge_c = np.clip(temperatures_c, 0.0, 40.0)
    at_edge = MODEL.correct(raw, edge_c, ModelInputs(time_s=np.zeros(len(stamps))))
    np.testing.assert_allclose(got, at_edge.rate_rad_s, rtol=0.0, atol=1e-12)
    beyond = np.array([t < 0.0 or t > 40.0 for t in temperatures_c])
    # The polynomial itself goes on beyond the range: the clamp makes the difference.
    x = (np.array(temperatures_c) - 20.0) / 20.0
    unclamped = raw[:, 0] - np.polynomial.polynomial.polyval(x, MODEL.terms[0].bias)
    assert np.all(np.abs(got[beyond, 0] - unclamped[beyond]) > 1e-4)
    # Every clamped sample is counted, and the status said so while they came.
    status = probe.wait_status(
        COMPENSATION_DIAGNOSTIC,
        lambda s: status_values(s)['samples_out'] == str(len(stamps)), TIMEOUT_S,
        'a status counting every sample', launcher)
    assert status_values(status)['temperature_clamped_samples'] == str(int(beyond.sum()))
    statuses = [s for name, seen in probe.diagnostics.items()
                if name.startswith(COMPENSATION_DIAGNOSTIC) for s in seen]
    assert any(s.level == DiagnosticStatus.WARN and
               s.message == 'temperature outside the calibrated range: clamped'
               for s in statuses)
    assert status_values(status)['model_error_temperatures'] == '0'


def expected_covariance(table: ModelErrorTable, temperature_c: float,
                        noise_rad_s=(NOISE_RAD_S, NOISE_RAD_S)) -> list:
    """Give the diagonal the node must publish: noise^2 + error^2, y unmeasured (0)."""
    error = table.error_at([temperature_c])[0]
    covariance = [0.0] * 9
    covariance[0] = noise_rad_s[0] ** 2 + error[0] ** 2
    covariance[8] = noise_rad_s[1] ** 2 + error[1] ** 2
    return covariance


def test_the_published_covariance_follows_the_model_error_table(launcher, probe, tmp_path):
    start_node(launcher, probe, tmp_path)
    feeder = Feeder(probe, launcher)
    # At the table's temperatures, between them, and held beyond its ends.
    temperatures_c = [10.0, 20.0, 30.0, -5.0, 45.0]
    stamps = feeder.send(temperatures_c)
    for temperature_c, msg in zip(temperatures_c, feeder.outputs(stamps)):
        assert list(msg.angular_velocity_covariance) == pytest.approx(
            expected_covariance(TABLE, temperature_c), rel=1e-12, abs=0.0), temperature_c
    log = launcher.processes[0].output()
    assert '/diagnostics (covariance: rate noise + model error at 2 temperatures)' in log
    at_20 = feeder.outputs(stamps)[1].angular_velocity_covariance
    assert at_20[0] == pytest.approx(NOISE_RAD_S ** 2 + 2e-3 ** 2, rel=1e-12)
    assert at_20[8] == pytest.approx(NOISE_RAD_S ** 2 + 1e-3 ** 2, rel=1e-12)

    # A table that is not one is refused at runtime, naming the parameter; a good one is taken.
    results = probe.set_parameters('compensation_node',
                                   {'model_error.temperature_c': [30.0, 10.0]})
    assert [r.successful for r in results] == [False]
    assert results[0].reason.startswith('invalid parameter model_error.temperature_c: model '
                                        'error temperatures must be strictly increasing')
    results = probe.set_parameters('compensation_node', {'model_error.x_rad_s': [5e-3, 5e-3]})
    assert [r.successful for r in results] == [True], results[0].reason
    changed = ModelErrorTable(TABLE.temperature_c, ((5e-3, 5e-3), TABLE.error_rad_s[1]))
    stamps = feeder.send([20.0, 30.0])
    for temperature_c, msg in zip([20.0, 30.0], feeder.outputs(stamps)):
        assert list(msg.angular_velocity_covariance) == pytest.approx(
            expected_covariance(changed, temperature_c), rel=1e-12, abs=0.0)

    # The noise of each axis (what diagnose and fit measure) takes the place of
    # rate_noise_rad_s; one per axis, or it is refused naming the parameter.
    results = probe.set_parameters('compensation_node', {'model_error.rate_noise_rad_s': [1e-3]})
    assert [r.successful for r in results] == [False]
    assert results[0].reason.startswith('invalid parameter model_error.rate_noise_rad_s: needs '
                                        'one finite noise >= 0 per axis (2: x, z)')
    results = probe.set_parameters('compensation_node',
                                   {'model_error.rate_noise_rad_s': [1e-3, 2e-4]})
    assert [r.successful for r in results] == [True], results[0].reason
    stamps = feeder.send([20.0])
    assert list(feeder.outputs(stamps)[0].angular_velocity_covariance) == pytest.approx(
        expected_covariance(changed, 20.0, (1e-3, 2e-4)), rel=1e-12, abs=0.0)
