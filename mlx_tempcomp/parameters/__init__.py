"""
The nodes' parameters and state on disk, without rclpy: specs, checks, models, files.

`specs` holds the `Spec` type, its checks and the parameters both nodes have;
`driver` and `compensation` each node's specs and the frozen settings they make
(`driver_settings`, `compensation_settings`), `tracking` the bias tracking's
(``bias_tracking.*``) and `learning` the field learning's (``learning.*``); `models` the
table of the models the compensation node runs (`MODELS`, `build_model`); `files` reading
a node's values from a parameter file and writing a fitted model's; `command_line` the
checks of the nodes' ROS command line on plain values; `state_file` the calibration state
the nodes keep on disk, `state_paths` where it is by default (under ROS_HOME, one file per
node); `launch_plan` what the launch file starts for its arguments. ``ros/declare.py``
declares the specs on a node in rclpy. Callers import the module they need.
"""

__all__ = ['command_line', 'compensation', 'driver', 'files', 'launch_plan', 'learning', 'models',
           'specs', 'state_file', 'state_paths', 'tracking']
