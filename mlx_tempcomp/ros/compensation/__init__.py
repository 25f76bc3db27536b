"""
The compensation node: the raw topics in, the compensated rate and temperature out.

By module: `inputs` (pairing the temperature and the model's other inputs with the
samples, the blocks the model takes), `outputs` (``imu/data``, ``imu/temperature`` and
their covariance), `status` (``/diagnostics`` and the start-up warnings),
`zro_recalibration` (the state file and the re-zero), `rest_hint` (the robot's rest hint
messages), `field_learning` (the learner's state, its diagnostics, the learned model's
file), `bias_tracking` (the tracker over each block, ``imu/gyro_bias``, its section of
the state file), `node` (`CompensationNode`, the executable's `main`).
"""
