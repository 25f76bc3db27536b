"""
Start nodes the Jazzy way: build them first, spin, stop cleanly; exit 1 on bad set-up.

SIGINT and SIGTERM are taken by a thread of ours, not by rclpy's handlers. rclpy's
handlers shut the context down from a thread of their own at any moment, and
chain SIGINT to Python's KeyboardInterrupt, raised at whatever line the main
thread runs next: a callback then fails half-way on an invalidated handle, the
nodes are destroyed on a shut-down context (once seen spinning for minutes in
``destroy_node``), and a KeyboardInterrupt landing in the clean-up turned a stop
into exit code 1. Here a signal only ends the spin between two callbacks; the
nodes are then destroyed, their summaries logged, while the context still works.
"""

import os
import signal
import threading

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.logging import get_logger
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from .declare import check_command_line, unknown_parameters
from ..errors import MlxTempCompError
from ..parameters.command_line import explain_parse_error

STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


def _stop_on_signals(stop: Future, logger_name: str) -> None:
    """
    Resolve ``stop`` at the first SIGINT or SIGTERM; exit at once at a second one.

    Python's C-level handler writes each signal to the wakeup pipe, from whichever
    thread the kernel picked (numpy's threads, DDS's); a thread of ours reads it and
    wakes the executor through ``stop``. The Python-level handlers, run later in the
    main thread, have nothing left to do.
    """
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    for signum in STOP_SIGNALS:
        signal.signal(signum, lambda *_: None)

    def watch():
        stop.set_result(os.read(read_fd, 1)[0])
        os.read(read_fd, 1)
        get_logger(logger_name).error('a second stop signal while stopping: exiting without '
                                      'clean-up')
        os._exit(1)
    threading.Thread(target=watch, daemon=True).start()


def run(node_factories, args=None, logger_name: str = 'mlx_tempcomp', connect=None) -> int:
    """
    Build each node with its factory, spin them all until a stop signal; return the exit code.

    ``connect(nodes)``, if given, links the built nodes before they spin.
    """
    stop = Future()
    _stop_on_signals(stop, logger_name)
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except rclpy_implementation.RCLError as err:
        get_logger(logger_name).fatal(f'cannot start: {explain_parse_error(str(err))}')
        return 1
    nodes = []
    try:
        for factory in node_factories:
            nodes.append(factory())
        for node in nodes:
            check_command_line(node, args)
    except MlxTempCompError as err:
        # What a user can get wrong at start (parameters, state file, device, bag, model):
        # one fatal log line and exit code 1.
        get_logger(logger_name).fatal(str(err))
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
        return 1
    for node in nodes:
        for warning in unknown_parameters(node):
            node.get_logger().warn(warning)
    if connect is not None:
        connect(nodes)
    executor = SingleThreadedExecutor()
    for node in nodes:
        executor.add_node(node)
    try:
        executor.spin_until_future_complete(stop)
    finally:
        if stop.done():
            get_logger(logger_name).info(f'{signal.Signals(stop.result()).name}: stopping')
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
