"""
Thin ROS 2 nodes that translate parameters and messages to core objects.

Two rooms, one per node, over what both share: `driver` (the driver node, its device
streams and the bag replay) and `compensation` (the compensation node and its parts:
pairing, outputs, status, bias tracking, field learning, the ZRO recalibration). Beside
them: `declare` (the parameters declared in rclpy from the specs), `messages`, `qos`,
`runner` (start-up, signals, the one fatal line), `service_window` (a service awaiting
its window of samples, the guard of the calibration calls); `bringup` and `demo` run
both nodes in one process. The rooms import the shared modules, never each other
(`test/test_layering.py`).
"""
