"""
Driver and compensation node in one process (``ros2 run mlx_tempcomp bringup``).

The driver hands each tick's raw messages straight to the compensation node
(`DriverNode.local_consumers`), which then has no raw subscriptions: no
serialising, no DDS, no executor wake-up per message between them. The raw
topics are still published for anyone else (a recorder, a second node).
"""

import functools

from .compensation.node import CompensationNode
from .driver.node import DriverNode
from .runner import run


def _hand_off(nodes) -> None:
    driver, compensation = nodes
    driver.local_consumers.append(compensation.take_local)


def main(args=None) -> int:
    return run([DriverNode, functools.partial(CompensationNode, local_input=True)], args,
               'bringup', connect=_hand_off)


if __name__ == '__main__':
    raise SystemExit(main())
