"""
The ``mlx-tempcomp inject-motion`` command: known motion added to a record taken at rest.

A schedule of rests and turns (`simulation.motion`: ``cycle`` rests 90 s every 5 min and
turns about every axis between, ``mixed`` rests 10 s to 10 min between slow, ramped and
fast turns about every axis and gravity) is drawn from ``--seed`` and added to the
record's gyro columns; the rate added is written as ``ref_x|y|z`` and the specific
force, when the record has one, turned with the sensor. The output is a canonical CSV
(``fit``, ``evaluate --track-bias`` and the rest read it as they read any record) with one
more column, ``rest_hint``: 1 in the schedule's rests, 0 in its turns, the truth a robot's
odometry would tell (``evaluate --track-bias --rest-hint rest_hint``); the schedule goes
to ``<stem>.schedule.json`` beside it. ``fit`` on the output fits the
bias to gyro minus ref, the record at rest; ``evaluate --track-bias`` judges the
tracker against the truth.
"""

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from .errors import UserError
from .loading import load, read_options
from .options import add_recording_options, non_negative_int
from .running import check_output_file, write_json
from ..core.errors import TempCompError
from ..recordings.csv_writer import write_csv
from ..simulation.motion import inject_motion, motion_schedule, REST, ScheduleSettings

SCHEDULES = ('cycle', 'mixed')
REST_HINT_COLUMN = 'rest_hint'
_CSV_FORMAT = '%.17g'   # round trip: the reference is exact


def _level_axes(recording) -> tuple:
    """Give the two sensor axes nearest the horizontal (x and y without an accelerometer)."""
    if recording.acceleration_m_s2 is None:
        return ('x', 'y')
    vertical = int(np.argmax(np.abs(np.mean(recording.acceleration_m_s2, axis=0))))
    return tuple(a for k, a in enumerate('xyz') if k != vertical)


def inject_motion_command(args: argparse.Namespace) -> int:
    check_output_file(args.out, '--out')
    out = Path(args.out)
    schedule_path = out.with_name(out.stem + '.schedule.json')
    recording = load(args.input, read_options(args))
    if recording.reference_rad_s is not None:
        msg = (f'{args.input} has a reference rate already (ref columns): inject motion into '
               'a record taken at rest')
        raise UserError(msg)
    try:
        settings = getattr(ScheduleSettings, args.schedule)(
            level_rests=not args.free_attitude, level_axes=_level_axes(recording))
        schedule = motion_schedule(recording.duration_s + 1e-9, settings, args.seed)
        injected = inject_motion(recording.time_s, recording.gyro_rad_s, recording.axes,
                                 schedule, recording.acceleration_m_s2)
    except TempCompError as err:
        raise UserError(f'{args.input}: {err}') from None
    moved = dataclasses.replace(recording, gyro_rad_s=injected.gyro_rad_s,
                                reference_rad_s=injected.reference_rad_s,
                                acceleration_m_s2=injected.acceleration_m_s2)
    # At rest in a rest segment and after the schedule's end (segment -1).
    resting = np.array([s.kind == REST for s in schedule.segments] + [True])
    rest_hint = resting[injected.segment].astype(int)
    try:
        write_csv(args.outputs.file(out), moved, _CSV_FORMAT, {REST_HINT_COLUMN: rest_hint})
        write_json(args.outputs.file(schedule_path), {
            'input': args.input, 'schedule': args.schedule, 'seed': args.seed,
            'settings': dataclasses.asdict(settings),
            'time_zero_s': float(recording.time_s[0]),
            'still_share': schedule.still_share, 'segments': schedule.to_json()})
    except OSError as err:
        msg = f'cannot write to {out.parent}: {err.strerror}'
        raise UserError(msg) from None
    turns = {}
    for segment in schedule.segments:
        if segment.kind != REST:
            turns.setdefault((segment.kind, segment.axis), set()).add(segment.turn)
    summary = ', '.join(f'{len(ids)} {kind} about {axis}'
                        for (kind, axis), ids in sorted(turns.items()))
    print(f'{args.schedule} schedule (seed {args.seed}) over {schedule.duration_s:.1f} s: '
          f'still {100 * schedule.still_share:.1f} % in {len(schedule.rests())} rests; turns: '
          f'{summary}')
    accelerometer = 'turned with the sensor' if injected.acceleration_m_s2 is not None else \
        'none in the record: turns about gravity are about z'
    print(f'specific force: {accelerometer}')
    print(f'wrote {out} (gyro with the motion, ref_{"|".join(recording.axes)}, '
          f'{REST_HINT_COLUMN} 1 at rest) and {schedule_path}')
    return 0


def add_parser(commands) -> None:
    """Add the ``inject-motion`` subcommand."""
    parser = commands.add_parser(
        'inject-motion', help='add known turns to a record taken at rest (ref columns)',
        description='Draw a schedule of rests and turns (slow 0.2-2 deg/s constant and '
                    'ramped, fast, about x, y, z and gravity), add it to the gyro of a record '
                    'taken at rest, turn its specific force with the sensor, and write a '
                    'CSV with the added rate as ref_x|y|z and the rest hint a robot would '
                    'give as rest_hint (1 at rest, 0 turning), to test the bias tracking '
                    '(evaluate --track-bias [--rest-hint rest_hint]) on your own unit: the '
                    "truth is known, the bias is the record's own.")
    add_recording_options(parser)
    parser.add_argument('--out', required=True, metavar='FILE.csv',
                        help='CSV to write; the schedule goes to <stem>.schedule.json')
    parser.add_argument('--schedule', choices=SCHEDULES, default='cycle',
                        help='cycle: still 30 %% of the time, a 90 s rest every 5 min, turns '
                             'about every axis between; mixed: rests of 10 s to 10 min '
                             'between stretches of turns (default: %(default)s)')
    parser.add_argument('--seed', type=non_negative_int, default=0, metavar='N',
                        help='seed of the schedule (default: %(default)s)')
    parser.add_argument('--free-attitude', action='store_true',
                        help='turns about the horizontal axes (x and y of a sensor lying '
                             'flat) do not come back: the sensor rests at whatever attitude '
                             'they leave (default: every rest level)')
    parser.set_defaults(handler=inject_motion_command, per_instance=True)
