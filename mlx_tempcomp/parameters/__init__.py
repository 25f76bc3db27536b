"""
The nodes' parameters and state on disk, without rclpy: specs, checks, models, files.

`specs` holds the `Spec` type, its checks and the parameters both nodes have;
`driver` and `compensation` each node's specs and the frozen settings
they make (`driver_settings`, `compensation_settings`); `models` the table of the
models the compensation node runs (`MODELS`, `build_model`); `files` reading
a node's values from a parameter file and writing a fitted model's;
`command_line` the checks of the nodes' ROS command line on plain values;
`state_file` the calibration state the nodes keep on disk. ``ros/declare.py``
declares the specs on a node in rclpy.
"""
