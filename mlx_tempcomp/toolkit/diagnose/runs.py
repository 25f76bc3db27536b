"""
The diagnoses ``mlx-tempcomp diagnose`` runs: one, or with records held out.

Several records of one unit are fitted as one; ``--test record`` holds out
the last, ``--test each`` each in turn (then diagnoses over all of them for
params.yaml). What they cannot do is refused before any work
(`check_records`); the re-zero window a held-out record is judged after
defaults to what a node needs on it (`held_out_rezero_s`).
"""

import dataclasses

from ..errors import UserError
from ..progress import Progress
from ...core.diagnosis import (DEFAULT_REZERO_S, default_rezero_s, diagnose as run_diagnosis,
                               DiagnosisSettings, rezero_window_rows)
from ...core.fitting import join_records

TEST_RECORD = 'record'
TEST_EACH = 'each'


class Bars:
    """One progress bar per phase the diagnosis reports."""

    def __init__(self, enabled):
        self.enabled = enabled
        self.bar = None
        self.label = None
        self.run = ''

    def __call__(self, done: int, total: int, label: str) -> None:
        label = f'{self.run}{label}'
        if label != self.label:
            self.close()
            self.bar = Progress(total, f'diagnose: {label}', self.enabled)
            self.label = label
        self.bar.total = max(int(total), 1)
        self.bar.update(done)

    def close(self) -> None:
        """Close the bar of the phase that runs."""
        if self.bar is not None:
            self.bar.close()
        self.bar = None


def check_records(records: list, test, exporting: bool) -> None:
    """
    Refuse what several records (or one, with --test record|each) cannot do, before work.

    ``exporting``: --px4-params or --ardupilot-parm was given.
    """
    twice = sorted({record for record in records if records.count(record) > 1})
    if twice:
        msg = f'{twice[0]} is given twice: give each record of the unit once'
        raise UserError(msg)
    if test in (TEST_RECORD, TEST_EACH) and len(records) < 2:
        msg = (f'{records[0]}: --test {test} holds out whole records: give two or more '
               'records of the unit, or --test F')
        raise UserError(msg)
    if len(records) > 1 and exporting:
        msg = ('--px4-params and --ardupilot-parm export the cubic of one record: give one '
               f'record, not {len(records)}')
        raise UserError(msg)


def error_text(records: list, err: Exception) -> str:
    """Name the record a diagnosis error is about, or every record when it is all of them."""
    text = str(err)
    if any(text.startswith(f'{record}:') for record in records):
        return text
    return f'{", ".join(records)}: {text}'


def diagnoses(recordings: list, settings: DiagnosisSettings, test, bars: Bars) -> tuple:
    """
    Return (the diagnosis written, those with a record held out).

    --test each first diagnoses with each record held out in turn (the
    others in the order given), then over all records for params.yaml.
    """
    if settings.test_record and test == TEST_EACH:
        records = join_records(recordings)
        for record in range(len(recordings)):  # refuse a short record before any work
            rezero_window_rows(records, record, settings.rezero_s)
        held_out = []
        for record, recording in enumerate(recordings):
            bars.run = f'record {record + 1} of {len(recordings)} held out: '
            others = recordings[:record] + recordings[record + 1:]
            held_out.append(run_diagnosis(others + [recording], settings, progress=bars))
        bars.run = 'all records: '
        written = run_diagnosis(recordings, dataclasses.replace(settings, test_record=False),
                                progress=bars)
        return written, tuple(held_out)
    diagnosis = run_diagnosis(recordings, settings, progress=bars)
    return diagnosis, (diagnosis,) if settings.test_record else ()


def held_out_rezero_s(given, recordings: list, test) -> float:
    """Give --rezero-s (``given``), or the window a node needs on the records held out."""
    if given is not None:
        return given
    if test == TEST_EACH:
        held_out = range(len(recordings))
    elif test == TEST_RECORD:
        held_out = (len(recordings) - 1,)
    else:
        return DEFAULT_REZERO_S
    return default_rezero_s(join_records(recordings), held_out)
