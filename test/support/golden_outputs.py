"""
Golden outputs: SHA-256 digests of what the commands write, to hold them bit-identical.

A refactor that must not change behaviour (issue 23's split of the
diagnosis, issue 26's clean-up) is checked by running the same commands
before and after and comparing every byte they write. Each `Case` is a list
of ``mlx-tempcomp`` command lines run in this process through
`mlx_tempcomp.cli.main` (the code path of the console script), in a scratch
folder with relative paths: the outputs name their inputs as the command
lines give them, and hold no timing, version or absolute path, so nothing
is normalised before hashing. ``test/golden/outputs.json`` keeps the
command lines and the digest of each output file (a command's printed
output is kept as a file when it is its result, as ``evaluate --json``'s).

The digests belong to one environment: numpy and its OpenBLAS (which picks
kernels by CPU) may change the last bits of a fit. They are regenerated on
purpose, with the change that moves them, when an issue changes behaviour::

    .venv/bin/python test/support/golden_outputs.py --write      # rewrite outputs.json
    .venv/bin/python test/support/golden_outputs.py --out DIR    # keep the outputs, compare

To see what changed, write the outputs of both commits and diff them (the
script runs the package of the checkout it lies in)::

    mkdir /tmp/golden-before && git archive <commit> | tar -x -C /tmp/golden-before
    .venv/bin/python /tmp/golden-before/test/support/golden_outputs.py --out /tmp/before
    .venv/bin/python test/support/golden_outputs.py --out /tmp/after
    diff -r /tmp/before /tmp/after

The measured case reads the measured thermal cycle where measured_data.py
finds it (MLX_TEMPCOMP_SHARED names the shared folder when the checkout does
not lie beside it, as in a worktree); it is skipped when that file is missing.
"""

import argparse
import contextlib
from dataclasses import dataclass
import hashlib
import io
import json
import os
from pathlib import Path
import shlex
import sys
import tempfile

from measured_data import MEASURED_CSV

ROOT = Path(__file__).resolve().parents[2]
STORED = Path(__file__).resolve().parent / 'golden' / 'outputs.json'
REGENERATE = '.venv/bin/python test/support/golden_outputs.py --write'


@dataclass(frozen=True)
class Command:
    """One ``mlx-tempcomp`` command line; ``stdout`` names the file its printed output goes to."""

    argv: tuple
    stdout: str = ''

    def line(self) -> str:
        """Give the command line as a shell would take it."""
        line = shlex.join(('mlx-tempcomp',) + self.argv)
        return f'{line} > {self.stdout}' if self.stdout else line


@dataclass(frozen=True)
class Case:
    """
    Commands run in turn in one scratch folder, and the files whose digests are kept.

    ``inputs`` maps a name in the folder to a file outside it, linked in
    first (so the outputs name it as the command line does).
    """

    name: str
    commands: tuple
    outputs: tuple
    inputs: tuple = ()

    def missing(self) -> list:
        """Give the inputs that are not on this machine."""
        return [str(path) for _, path in self.inputs if not Path(path).is_file()]

    def lines(self) -> list:
        """Give the command lines."""
        return [command.line() for command in self.commands]


# A chamber cycled twice between 60 and -10 C at 1 Hz on two axes, with a thermal lag, a
# hysteresis and a supply voltage that moves the ZRO: diagnose adds the supply voltage to x,
# names a record effect as z's cause and writes the cubic on z; fit chooses orders; evaluate
# runs the diagnosed params.yaml over the record.
SIMULATED = Case('simulated', (
    Command(('simulate', '--out', 'sim.csv', '--axes', 'x,z', '--seed', '3', '--rate-hz', '1',
             '--cycle-c', '60', '-10', '60', '-10', '--ramp-c-per-min', '3', '--hold-s', '300',
             '--thermal-lag-s', '150', '--hysteresis-dps', '0.3', '--hysteresis-width-c', '4',
             '--supply-v', '0:4.7', '3000:5.3', '6000:4.9', '--zro-supply-dps-per-v', '1.5')),
    Command(('diagnose', 'sim.csv', '--test', '0.25', '--out', 'diagnose')),
    Command(('fit', 'sim.csv', '--out', 'fit.yaml')),
    Command(('evaluate', 'sim.csv', '--params', 'diagnose/params.yaml', '--json'),
            stdout='evaluate.json'),
), ('sim.csv', 'diagnose/params.yaml', 'diagnose/report.json', 'fit.yaml', 'evaluate.json'))

# The measured thermal cycle (three axes, 8400 rows): diagnose adds a temperature rate and a
# thermal gradient to x, writes the cubic on y (it loses round-robin); fit as a user runs it.
MEASURED = Case('measured', (
    Command(('diagnose', 'imu_raw_data.csv', '--preset', 'tofupilot', '--test', '0.25',
             '--out', 'diagnose')),
    Command(('fit', 'imu_raw_data.csv', '--preset', 'tofupilot', '--out', 'fit.yaml')),
), ('diagnose/params.yaml', 'diagnose/report.json', 'fit.yaml'),
    inputs=(('imu_raw_data.csv', str(MEASURED_CSV)),))

CASES = (SIMULATED, MEASURED)


def digest(path: Path) -> str:
    """Give the SHA-256 of a file's bytes."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def run_case(case: Case, folder: Path) -> dict:
    """Run the commands of ``case`` in ``folder`` (created); give {output: SHA-256}."""
    # Imported here: run as a script, main() first puts this checkout's package on sys.path.
    from mlx_tempcomp.cli import main
    folder.mkdir(parents=True, exist_ok=True)
    for name, path in case.inputs:
        (folder / name).symlink_to(path)
    with contextlib.chdir(folder):
        for command in case.commands:
            stdout, stderr = io.StringIO(), io.StringIO()
            with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
                code = main(list(command.argv))
            if code != 0:
                msg = f'{case.name}: `{command.line()}` ended with {code}: {stderr.getvalue()}'
                raise RuntimeError(msg)
            if command.stdout:
                Path(command.stdout).write_text(stdout.getvalue(), encoding='utf-8')
    return {name: digest(folder / name) for name in case.outputs}


def load() -> dict:
    """Give the stored command lines and digests: {case: {'commands', 'outputs'}}."""
    return json.loads(STORED.read_text(encoding='utf-8'))['cases']


def changes(case: Case, stored: dict, digests: dict) -> list:
    """Give one line per difference between a case's stored entry and this run."""
    entry = stored.get(case.name)
    if entry is None:
        return [f'{case.name}: not in {STORED.name}']
    found = []
    if entry['commands'] != case.lines():
        found.append(f'{case.name}: the command lines differ from the stored ones')
    for name in sorted(set(entry['outputs']) | set(digests)):
        before, after = entry['outputs'].get(name), digests.get(name)
        if before != after:
            found.append(f'{case.name}/{name}: stored {before}, now {after}')
    return found


def mismatch_message(found: list, folder: Path) -> str:
    """Say what changed, where this run's outputs are, and how to diff or regenerate."""
    return '\n'.join([
        'golden outputs changed:', *('  ' + line for line in found),
        f"this run's outputs are in {folder}.",
        'Behaviour was to stay bit-identical: to see what moved, write the outputs of the commit '
        'the digests come from (git log -1 -- test/golden/outputs.json) and diff them:',
        '  mkdir /tmp/golden-before && git archive <commit> | tar -x -C /tmp/golden-before',
        '  .venv/bin/python /tmp/golden-before/test/golden_outputs.py --out /tmp/before',
        f'  diff -r /tmp/before/<case> {folder}',
        f'If the change is meant, regenerate and commit the digests with it: {REGENERATE}'])


def _run_all(out: Path) -> dict:
    """Run every case whose inputs are here into out/<case>; give {case: digests or None}."""
    results = {}
    for case in CASES:
        if case.missing():
            print(f'{case.name}: skipped, missing {", ".join(case.missing())}')
            results[case.name] = None
            continue
        results[case.name] = run_case(case, out / case.name)
        print(f'{case.name}: ran {len(case.commands)} commands in {out / case.name}')
    return results


def _write(results: dict) -> None:
    missing = [name for name, digests in results.items() if digests is None]
    if missing:
        msg = f'cannot write {STORED}: cases {", ".join(missing)} lack their inputs'
        raise SystemExit(msg)
    cases = {case.name: {'commands': case.lines(), 'outputs': results[case.name]}
             for case in CASES}
    about = ('SHA-256 of the files the commands write, run in a scratch folder by '
             'test/support/golden_outputs.py (see its docstring); test_golden_outputs.py holds '
             'them. '
             f'Regenerate on purpose, with the change that moves them: {REGENERATE}')
    STORED.parent.mkdir(exist_ok=True)
    STORED.write_text(json.dumps({'about': about, 'cases': cases}, indent=2) + '\n',
                      encoding='utf-8')
    print(f'wrote {STORED}')


def main(argv=None) -> int:
    """Run the cases; compare their digests with the stored ones, or store them (--write)."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    parser.add_argument('--write', action='store_true',
                        help=f'rewrite {STORED.relative_to(ROOT)} from this run')
    parser.add_argument('--out', type=Path,
                        help='folder to keep the outputs in, one subfolder per case '
                             '(default: a temporary folder, removed)')
    args = parser.parse_args(argv)
    # The package of this checkout, whichever checkout the virtual environment was made for.
    sys.path.insert(0, str(ROOT))
    with contextlib.ExitStack() as stack:
        out = args.out or Path(stack.enter_context(tempfile.TemporaryDirectory()))
        if args.out and args.out.exists() and any(args.out.iterdir()):
            raise SystemExit(f'--out {args.out} is not empty')
        import mlx_tempcomp
        print(f'package: {os.path.dirname(mlx_tempcomp.__file__)}')
        results = _run_all(out.resolve())
        if args.write:
            _write(results)
            return 0
        stored = load()
        found = [line for case in CASES if results[case.name] is not None
                 for line in changes(case, stored, results[case.name])]
        print('\n'.join(found) if found else 'every output matches the stored digests')
        return 1 if found else 0


if __name__ == '__main__':
    sys.exit(main())
