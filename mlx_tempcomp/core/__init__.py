"""
Numpy-only core: the maths of the package, in rooms; nothing here imports rclpy.

Each room is a sub-package whose ``__init__`` says what it holds and lists what the
rest of the package takes from it (``__all__``); a room imports only the rooms below it
(docs/architecture.md, "The rooms of core"), bottom first:

- `series`: time-series helpers: pairing streams by stamp, error and noise figures;
- `mlx90609`: the MLX90609's own formulas and tables: EEPROM, factory table, conversions;
- `node_models`: the models the compensation node runs, the ZRO offset, the model
  error, the correction table any model may carry, the rate-table chain;
- `effects`: the effect model, its table of effects and their bias terms;
- `fitting`: fitting and validation: held-out blocks, PX4's cubic, the bias polynomial,
  the chain's fit, several records of one unit, the fleet prior;
- `standstill`: the gyro at rest: the standstill detector, rest hints, the bias
  tracker, its bounds, the recalibration window's checks;
- `learning`: field learning, the model renewed from the tracker's rests;
- `diagnosis`: the closed loop of ``mlx-tempcomp diagnose``;
- `procedures`: the at-rest procedures of the ADIS16130 and the MPU-6000.

`errors` holds the core's error classes, which every room may raise.
"""

__all__ = ['diagnosis', 'effects', 'errors', 'fitting', 'learning', 'mlx90609', 'node_models',
           'procedures', 'series', 'standstill']
