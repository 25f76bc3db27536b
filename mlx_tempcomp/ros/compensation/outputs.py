"""
The compensation node's outputs: ``imu/data`` and ``imu/temperature``, and what went out.

The input messages go out again with the rate rewritten (acceleration and
orientation pass through); the angular velocity covariance is per axis the
white noise of a sample squared (``model_error.rate_noise_rad_s``, else
``rate_noise_rad_s``), plus the variance of the tracked offset while bias
tracking runs, else the square of the model's error at the sample's
temperature when ``model_error.*`` gives a table. While the tracking says
the gyro is still, the rate published is checked against that covariance
(`StillWindows`: the truth there is 0), for ``/diagnostics``.
"""

from sensor_msgs.msg import Imu, Temperature

from .inputs import InputBlock
from .. import messages
from ..qos import stream_publisher
from ...core.node_models import StillWindows
from ...parameters.compensation import CompensationSettings


class CompensationOutputs:
    """
    Publish corrected blocks and count them.

    ``clamped_recent`` says a sample was clamped since the last status.
    """

    def __init__(self, node, settings: CompensationSettings, indices: tuple,
                 temperature_streams: tuple):
        self.imu_publisher = stream_publisher(node, Imu, 'imu/data')
        self.temperature_publisher = stream_publisher(node, Temperature, 'imu/temperature')
        self.indices = indices
        self.temperature_streams = temperature_streams
        self.configure(settings)
        self.samples_out = 0
        self.blocks = 0
        self.largest_block = 0
        self.clamped_samples = 0
        self.clamped_recent = False

    def configure(self, settings: CompensationSettings) -> None:
        """Take the settings the covariance depends on: the noise, the model error table."""
        self.noise_rad_s = settings.covariance_noise_rad_s
        self.covariance = messages.diagonal_covariance(self.indices,
                                                       [n * n for n in self.noise_rad_s])
        self.model_error = settings.model_error
        self._tracked = (None, None)   # the last tracked std and its covariance
        # A new covariance is judged afresh.
        self.still_windows = StillWindows()

    def publish(self, block: InputBlock, rates: list, clamped: int, stds=None,
                still: bool = False) -> None:
        """
        Publish the corrected rows of ``block`` and their temperatures; count them.

        ``stds``: per row, the tracked offset's standard deviation per axis (None: no
        tracking); ``still``: the tracking says the gyro is still.
        """
        streams = self.temperature_streams
        covariances = self.covariances(block.temperature_c) if stds is None else \
            self.tracked_covariances(stds)
        for parts, temperatures, rate, covariance in zip(
                block.messages, block.temperature_c, rates, covariances):
            # The input messages go out again, rate rewritten (the rest passes through
            # unchanged): building new ones would cost more than the model.
            imu = parts['imu']
            if not block.has_temperature:
                pass   # the driver sends none: no temperature goes out with the sample
            elif len(streams) == 1:
                self.temperature_publisher.publish(parts[streams[0]])
            else:
                self.temperature_publisher.publish(messages.temperature_message(
                    imu.header.stamp, imu.header.frame_id,
                    sum(temperatures) / len(temperatures), parts[streams[0]].variance))
            self.imu_publisher.publish(messages.set_rates(imu, self.indices, rate, covariance))
        if stds is not None and any(self.noise_rad_s):
            for stamp_ns, rate, std in zip(block.stamps_ns, rates, stds):
                self.still_windows.add(stamp_ns * 1e-9, rate, std, self.noise_rad_s,
                                       still)
        if clamped:
            self.clamped_samples += clamped
            self.clamped_recent = True
        self.samples_out += len(rates)
        self.blocks += 1
        self.largest_block = max(self.largest_block, len(rates))

    def covariances(self, temperatures: list) -> list:
        """
        Give the angular velocity covariance of each sample at its temperatures.

        The noise^2 per axis, plus the model error's square at the temperature
        when a table is given; with the noise unknown (0) it stays all 0.
        """
        noise = self.noise_rad_s
        if self.model_error is None or not any(noise):
            return [self.covariance] * len(temperatures)
        return [messages.diagonal_covariance(self.indices, row)
                for row in self.model_error.variance(noise, temperatures).tolist()]

    def tracked_covariances(self, stds: list) -> list:
        """
        Give the covariance of tracked rows: noise^2 + the offset's variance, per axis.

        The tracked offset's standard deviation takes the place of the model error:
        it is the bias error left after tracking (at most ``initial_std_rad_s``, the
        model's own). With the noise unknown (0) it stays all 0. The standard
        deviation changes once a window: the last covariance is reused.
        """
        noise = self.noise_rad_s
        if not any(noise):
            return [self.covariance] * len(stds)
        covariances = []
        last_std, last = self._tracked
        for std in stds:
            if std != last_std:
                last_std = std
                last = messages.diagonal_covariance(self.indices,
                                                    [n * n + s * s for n, s in zip(noise, std)])
            covariances.append(last)
        self._tracked = last_std, last
        return covariances
