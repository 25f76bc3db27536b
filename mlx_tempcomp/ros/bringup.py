"""Simulated driver and compensation nodes in one process (``ros2 run mlx_tempcomp bringup``)."""

from .compensation_node import CompensationNode
from .driver_node import DriverNode
from .runner import run


def main(args=None) -> int:
    return run([DriverNode, CompensationNode], args, 'bringup')


if __name__ == '__main__':
    raise SystemExit(main())
