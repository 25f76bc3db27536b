"""
Where the measured data lies: ``shared/`` beside the repository, never copied into it.

MEASURED_CSV is the measured thermal cycle, FLIGHT_LOGS the folder of the four small
flight-controller logs (data/flight_logs, its README.md gives their figures).

Looked up in order: the folder named by MLX_TEMPCOMP_SHARED; ``shared`` beside
this checkout; ``shared`` beside the checkout this one was cloned from (CI
clones the repository into a scratch folder), or whose worktree this is. Tests skip
when none holds it.
"""

import os
from pathlib import Path
import subprocess

RELATIVE = Path('data') / 'tofupilot_imu_thermal_sweep' / 'imu_raw_data.csv'
_ROOT = Path(__file__).resolve().parents[2]


def _git(*arguments) -> str:
    try:
        return subprocess.run(['git', '-C', str(_ROOT), *arguments], capture_output=True,
                              text=True, check=False).stdout.strip()
    except OSError:
        return ''


def _origin() -> list:
    """``shared`` beside the repository this one was cloned from, or whose worktree it is."""
    url = _git('config', '--get', 'remote.origin.url')
    common = _git('rev-parse', '--path-format=absolute', '--git-common-dir')
    checkouts = ([Path(url)] if url and Path(url).is_dir() else []) + \
        ([Path(common).parent] if common else [])
    return [checkout.parent / 'shared' for checkout in checkouts]


def _shared(relative: Path) -> Path:
    folders = ([Path(os.environ['MLX_TEMPCOMP_SHARED'])] if 'MLX_TEMPCOMP_SHARED' in os.environ
               else []) + [_ROOT.parent / 'shared'] + _origin()
    for folder in folders:
        if (folder / relative).exists():
            return folder / relative
    return folders[0] / relative


MEASURED_CSV = _shared(RELATIVE)
FLIGHT_LOGS = _shared(Path('data') / 'flight_logs')
