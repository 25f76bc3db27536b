"""
How many examples a property-based test draws: its full count, or a quarter in the fast tier.

``make test`` (and CI) draw the counts the test modules give. ``make test-fast`` loads the
``fast`` profile (test/conftest.py: the same fixed examples as ``ci``), where each test
draws a quarter of its count, at least 10: every property is still tried while working,
the full search is the whole suite's.
"""

import os


def examples(count: int) -> int:
    """Give the examples a test of ``count`` draws in this run's tier."""
    return max(10, count // 4) if os.environ.get('HYPOTHESIS_PROFILE') == 'fast' else count
