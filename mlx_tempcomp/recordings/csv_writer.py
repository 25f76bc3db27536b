"""Write a `Recording` as a CSV that `csv_reader` reads back with the default columns."""

from pathlib import Path

import numpy as np

from .recording import AXES, Recording


def csv_columns(recording: Recording) -> dict:
    """Give the recording's columns by CSV header name, the optional ones where present."""
    columns = {'time': recording.time_s, 'temperature': recording.temperature_c}
    columns.update((f'gyro_{a}', recording.gyro_rad_s[:, i])
                   for i, a in enumerate(recording.axes))
    if recording.reference_rad_s is not None:
        columns.update((f'ref_{a}', recording.reference_rad_s[:, i])
                       for i, a in enumerate(recording.axes))
    if recording.acceleration_m_s2 is not None:
        columns.update((f'acc_{a}', recording.acceleration_m_s2[:, i])
                       for i, a in enumerate(AXES))
    if recording.temperature_2_c is not None:
        columns['temperature_2'] = recording.temperature_2_c
    if recording.supply_voltage_v is not None:
        columns['supply_voltage'] = recording.supply_voltage_v
    return columns


def write_csv(path: Path, recording: Recording, number_format: str, extra=None) -> None:
    """
    Write ``recording`` to ``path`` (numbers as ``number_format``); OSError if it cannot.

    ``extra`` (header name -> one value per row) follows the recording's columns.
    """
    columns = {**csv_columns(recording), **(extra or {})}
    np.savetxt(path, np.column_stack(list(columns.values())), fmt=number_format,
               delimiter=',', header=','.join(columns), comments='')
