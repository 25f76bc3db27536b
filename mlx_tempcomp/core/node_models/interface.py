"""
What every compensation model offers the node and the toolkit, and the inputs it may need.

A model maps raw rate (rad/s, (samples, axes)) and temperature (degC,
(samples,) or (samples, axes)) to corrected rate; some of its effects need
more, named by the fields of `ModelInputs` (the table `INPUTS` says what a
record must hold for each). A model lists what it needs in ``inputs``; the
node subscribes to those, the toolkit asks a record for them.
"""

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class ModelInputs:
    """
    The inputs beyond rate and temperature; None: not given.

    For a block, arrays of one row per sample: ``time_s`` (samples,) s,
    ``temperature_2_c`` (samples,) degC, ``acceleration_m_s2`` (samples, 3)
    m/s^2 (specific force), ``supply_voltage_v`` (samples,) V; for
    `ModelStream.correct_one`, one row's values.
    """

    time_s: Any = None
    temperature_2_c: Any = None
    acceleration_m_s2: Any = None
    supply_voltage_v: Any = None

    def rows(self) -> 'ModelInputs':
        """Give one row's values as a block of one row."""
        return ModelInputs(*(None if value is None else [value] for value in vars(self).values()))


NO_INPUTS = ModelInputs()


@dataclass(frozen=True)
class Input:
    """One field of `ModelInputs`: the shape of one sample's value, the record columns."""

    name: str
    shape: tuple
    columns: tuple


# What a record (CSV or bag) holds each input in: `Recording` has the same field names.
INPUTS = {
    'time_s': Input('time_s', (), ('time',)),
    'temperature_2_c': Input('temperature_2_c', (), ('temperature_2',)),
    'acceleration_m_s2': Input('acceleration_m_s2', (3,), ('acc_x', 'acc_y', 'acc_z')),
    'supply_voltage_v': Input('supply_voltage_v', (), ('supply_voltage',)),
}


@dataclass(frozen=True)
class CorrectedRate:
    """Corrected rate in rad/s and which samples had their temperature clamped."""

    rate_rad_s: np.ndarray
    temperature_clamped: np.ndarray


@runtime_checkable
class ModelStream(Protocol):
    """Runs a model block by block, keeping the state of its stateful effects."""

    model: 'CompensationModel'

    def correct_block(self, rates_rad_s, temperatures_c,
                      inputs: ModelInputs = NO_INPUTS) -> CorrectedRate:
        """Correct the next rows of the stream."""

    def correct_one(self, rates_rad_s: list, temperatures_c: list,
                    inputs: ModelInputs = NO_INPUTS) -> tuple:
        """Correct one row: (rad/s per axis as a list, any clamped), bits as a block of one."""


@runtime_checkable
class CompensationModel(Protocol):
    """
    A model the compensation node runs: EEPROM, polynomial, linear BTC, effects, chain.

    ``inputs`` names the `ModelInputs` fields it needs; the ZRO offset is the
    residual learned at rest, in ``offset_unit``, taken off last.
    """

    name: str
    axes: int
    inputs: frozenset
    offset_unit: str
    zro_offset: tuple

    def fingerprint(self) -> str:
        """Give a short hash of the model without its ZRO offset."""

    def correct(self, rate_rad_s, temperature_c,
                inputs: ModelInputs = NO_INPUTS) -> CorrectedRate:
        """Correct a batch; stateful effects start at its first sample."""

    def stream(self) -> ModelStream:
        """Give a runner whose state starts empty."""

    def with_zro_offset(self, offset) -> 'CompensationModel':
        """Give the model with another ZRO offset."""

    def learn_zro_offset(self, rate_rad_s, temperature_c, corrected_rad_s) -> np.ndarray:
        """Give the total offset that zeroes readings taken at rest."""

    def offset_rad_s(self, temperature_c: float) -> np.ndarray:
        """Give the ZRO offset as rate at ``temperature_c``."""
