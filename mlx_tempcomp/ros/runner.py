"""Start nodes the Jazzy way: build them first, spin, shut down cleanly; exit 1 on bad set-up."""

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.logging import get_logger

from .params import ParameterError
from ..core.errors import TempCompError
from ..hardware.errors import HardwareError
from ..sources.bag import BagError
from ..state_file import StateFileError

# What a user can get wrong at start: each becomes one fatal log line and exit code 1.
SETUP_ERRORS = (ParameterError, TempCompError, HardwareError, BagError, StateFileError)


def run(node_factories, args=None, logger_name: str = 'mlx_tempcomp', connect=None) -> int:
    """
    Build each node with its factory, spin them all until shutdown; return the exit code.

    ``connect(nodes)``, if given, links the built nodes before they spin.
    """
    try:
        rclpy.init(args=args)
    except rclpy_implementation.RCLError as err:
        # A --params-file rcl cannot parse (e.g. an unquoted y, a boolean in YAML 1.1).
        get_logger(logger_name).fatal(f'cannot start: {err}')
        return 1
    nodes = []
    try:
        for factory in node_factories:
            nodes.append(factory())
    except SETUP_ERRORS as err:
        rclpy.logging.get_logger(logger_name).fatal(str(err))
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
        return 1
    if connect is not None:
        connect(nodes)
    executor = SingleThreadedExecutor()
    for node in nodes:
        executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:  # noqa: B902
        # SIGINT/SIGTERM shut the context down from the signal handler; a callback the
        # executor was taking then fails on its invalidated handle (RuntimeError from
        # take_message). That is a stop, not a crash; anything else still raises.
        if rclpy.ok():
            raise
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
