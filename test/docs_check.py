r"""
Run the marked command blocks of README.md and docs/*.md and compare what they print.

A fenced block is marked by an HTML comment on the line before it (blank lines
between are allowed); Markdown renders nothing of it::

    <!-- docs-check -->
    ```sh
    mlx-tempcomp fit cycle.csv --out cycle.yaml
    ```

    <!-- docs-check: output -->
    ```
    wrote cycle.yaml (model polynomial)
    ```

The marks, one per block, with options after ``;``:

- ``docs-check`` before a ``sh`` block: run it (``bash -e -o pipefail``); it
  must exit with 0, or with ``exit N``.
- ``docs-check`` before a ``console`` block: its ``$ `` lines (and their
  ``\`` continuations) are run, every other line is what they print.
- ``docs-check: output`` before any block: what the last run block printed.
- ``docs-check: figures`` before a table or paragraph: every number in it
  with a decimal point is one the last run block printed, to its digits.
- ``docs-check: by hand: REASON`` before a ``sh`` or ``console`` block: not
  run; the reason says why (a long benchmark, a robot with ROS installed).
- ``docs-check: set-up`` (README.md, once): the set-up every doc starts from.

Every ``sh`` and ``console`` block carries one of them, and a block of
another kind that starts like a command is an error: a command in the docs
is either checked or says why not.

Printed output (stdout and stderr together, as on a terminal) is compared
line by line with the doc's: text exactly, numbers to the digits the doc
prints (``1.94x`` in the doc holds for a printed ``1.94x`` or ``1.9412x``,
not ``1.95x``). ``...`` stands for any text within a line, and a line of
only ``...`` for any number of lines (a path in a temporary folder, the
part of a long output the doc leaves out). Lines that vary from run to run
are declared on the output block, ``ignore 'REGEX'``: a doc line matching
REGEX matches a printed line that matches it too, whatever else it holds.

Each doc runs in a scratch folder of its own, made by README's set-up
block (run from the repository root: the virtual environment on PATH,
``$REPO`` the repository, ``$SHARED`` the shared data, then ``cd`` into a
new temporary folder); its blocks run there in order, sharing files but not
shell variables, and the nodes they start in a localhost-only ROS domain that
no test session holds (claimed as test/conftest.py claims one), with a ROS_HOME
of the doc's own (where the nodes keep their state files by default). When the
set-up's ``$SHARED`` does not exist (a worktree), the shared folder is looked
up as the tests do (test/measured_data.py), and without it the blocks that
name ``$SHARED`` are skipped, saying so.

Usage (from anywhere; after ``make venv``)::

    .venv/bin/python test/docs_check.py [DOC ...]    # run and compare; exit 1 on a mismatch
    .venv/bin/python test/docs_check.py --list       # which blocks are checked, which not
    .venv/bin/python test/docs_check.py --jobs 2     # two docs at once (make docs-check)
"""

import argparse
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
MARK = re.compile(r'^\s*<!--\s*docs-check\b:?\s*(.*?)\s*-->\s*$')
FENCE = re.compile(r'^(\s*)(```+|~~~+)\s*([\w-]*)')
NUMBER = r'(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?'
NUMBER_GROUP = f'({NUMBER})'
# The first word of a block that is a command, to catch one left without a mark.
COMMAND_START = re.compile(r'^(\$ |mlx-tempcomp |\.venv/|python3? |make |cd |git |ros2 |colcon '
                           r'|dask |export |MLX_TEMPCOMP_|driver_node |compensation_node )')
RUN_KINDS = ('sh', 'console')
DEFAULT_TIMEOUT_S = 600


class MarkError(Exception):
    """A mark that cannot be read, or a command block without one."""


@dataclass
class Block:
    """One fenced block of a doc and its mark."""

    doc: Path
    line: int            # of the fence's first line, 1-based
    kind: str            # the fence's language: sh, console, text, ... ('' for none)
    lines: list          # the block's lines, without the fences
    mark: str = ''       # '', 'run', 'output', 'figures', 'by hand', 'set-up'
    reason: str = ''
    ignore: list = field(default_factory=list)
    exit_code: int = 0
    timeout_s: float = DEFAULT_TIMEOUT_S

    @property
    def where(self) -> str:
        return f'{self.doc.relative_to(ROOT) if self.doc.is_relative_to(ROOT) else self.doc}:' \
            f'{self.line}'


@dataclass
class Mismatch:
    """A doc line that the printed output does not hold."""

    where: str
    expected: str
    actual: str


def _options(block: Block, text: str) -> None:
    """Read the mark ``text`` (what follows ``docs-check``) into ``block``."""
    parts = [part.strip() for part in re.findall(r"(?:[^;']|'[^']*')+", text)]
    head = parts[0] if parts else ''
    if head.startswith('by hand'):
        block.mark, block.reason = 'by hand', head.partition(':')[2].strip()
        if not block.reason:
            raise MarkError(f'{block.where}: "by hand" needs a reason: by hand: WHY')
        return
    if head in ('output', 'figures', 'set-up'):
        block.mark, parts = head, parts[1:]
    else:
        block.mark = 'run'
    for part in parts:
        name, _, value = part.partition(' ')
        value = value.strip()
        if name == 'ignore':
            if len(value) < 2 or value[0] != "'" or value[-1] != "'":
                raise MarkError(f"{block.where}: ignore takes one quoted regex: ignore 'REGEX'")
            block.ignore.append(re.compile(value[1:-1]))
        elif name == 'exit' and value.isdigit():
            block.exit_code = int(value)
        elif name == 'timeout' and value.replace('.', '', 1).isdigit():
            block.timeout_s = float(value)
        else:
            raise MarkError(f'{block.where}: unknown option {part!r} in the docs-check mark')


def read_blocks(doc: Path, text: str = None) -> list:
    """Give the fenced blocks of ``doc`` with their marks (``text``: the doc's, if given)."""
    lines = (doc.read_text(encoding='utf-8') if text is None else text).splitlines()
    blocks, mark, index = [], None, 0
    while index < len(lines):
        found, fence = MARK.match(lines[index]), FENCE.match(lines[index])
        if found:
            mark = (found.group(1), index + 1)
        elif fence:
            end = _fence_end(doc, lines, index, fence.group(2))
            indent = len(fence.group(1))
            block = Block(doc, index + 1, fence.group(3),
                          [body[indent:] for body in lines[index + 1:end]])
            if mark:
                _options(block, mark[0])
            blocks.append(block)
            mark, index = None, end
        elif mark and lines[index].strip():
            figures = Block(doc, index + 1, 'text', _paragraph(lines, index))
            _options(figures, mark[0])
            if figures.mark != 'figures':
                raise MarkError(f'{figures.where}: this docs-check mark must precede a code block')
            blocks.append(figures)
            mark, index = None, index + len(figures.lines) - 1
        index += 1
    _check_marks(blocks)
    return blocks


def _fence_end(doc: Path, lines: list, index: int, fence: str) -> int:
    """Give the index of the line closing the fence opened at ``index``."""
    close = re.compile(r'^\s*' + re.escape(fence[0]) + '{' + str(len(fence)) + r',}\s*$')
    for end in range(index + 1, len(lines)):
        if close.match(lines[end]):
            return end
    raise MarkError(f'{doc}:{index + 1}: a code fence that is never closed')


def _paragraph(lines: list, index: int) -> list:
    """Give the lines from ``index`` up to the next blank line."""
    end = index
    while end < len(lines) and lines[end].strip():
        end += 1
    return lines[index:end]


def _check_marks(blocks: list) -> None:
    """Refuse a command block without a mark, and marks that do not fit their block."""
    for block in blocks:
        first = next((line for line in block.lines if line.strip()), '')
        if block.kind in RUN_KINDS and not block.mark:
            raise MarkError(f'{block.where}: a {block.kind} block without a docs-check mark: '
                            'mark it <!-- docs-check --> or <!-- docs-check: by hand: WHY -->')
        if block.kind not in RUN_KINDS and block.mark in ('run', 'by hand', 'set-up'):
            raise MarkError(f'{block.where}: only a sh or console block is run; this one is '
                            f'{block.kind!r}')
        if not block.kind and not block.mark and COMMAND_START.match(first):
            raise MarkError(f'{block.where}: this block reads as a command ({first.strip()!r}): '
                            'make it a sh block with a docs-check mark, or a text block (```text)')


def commands_and_output(block: Block) -> tuple:
    """
    Give the script a block runs, and the output it shows with the doc's line numbers.

    A ``sh`` block shows no output of its own (None); a ``console`` block's
    ``$ `` lines and their continuations are the script, the other lines its output.
    """
    if block.kind != 'console':
        return '\n'.join(block.lines) + '\n', None, None
    script, output, numbers, continued = [], [], [], False
    for offset, line in enumerate(block.lines):
        if continued or line.startswith('$ '):
            script.append(line if continued else line[2:])
            continued = line.rstrip().endswith('\\')
        else:
            output.append(line)
            numbers.append(block.line + 1 + offset)
    return '\n'.join(script) + '\n', output, numbers


def _number_format(expected: str) -> str:
    """Give the format spec that prints a number with the digits of ``expected``."""
    sign = '+' if expected.startswith('+') else ''
    mantissa, _, exponent = expected.lower().partition('e')
    decimals = len(mantissa.partition('.')[2])
    return f'{sign}.{decimals}{"e" if exponent else "f"}'


def same_number(expected: str, actual: str) -> bool:
    """Say whether ``actual`` printed with the digits of ``expected`` is ``expected``."""
    if expected == actual:
        return True
    try:
        value = float(actual)
        shown = format(value, _number_format(expected))
        return shown == expected or float(shown) == float(expected)
    except ValueError:
        return False


def _line_pattern(expected: str):
    """Give the regex a doc line makes: text as is, numbers captured, ``...`` any text."""
    pieces = []
    for part_index, part in enumerate(expected.split('...')):
        if part_index:
            pieces.append('(?:.*?)')
        position = 0
        for number in re.finditer(NUMBER, part):
            pieces.append(re.escape(part[position:number.start()]))
            pieces.append(NUMBER_GROUP)
            position = number.end()
        pieces.append(re.escape(part[position:]))
    return re.compile(''.join(pieces))


def line_matches(expected: str, actual: str, ignore: list = ()) -> bool:
    """Say whether a printed line is the doc's line (see the module's docstring)."""
    for pattern in ignore:
        if pattern.search(expected):
            return bool(pattern.search(actual))
    found = _line_pattern(expected).fullmatch(actual)
    if not found:
        return False
    numbers = re.findall(NUMBER, expected.replace('...', '\n'))
    return all(same_number(want, got) for want, got in zip(numbers, found.groups()))


def compare(expected: list, actual: list, ignore: list = (), numbers: list = None) -> list:
    """
    Give the mismatches between the doc's lines and the printed ones ([] when they agree).

    ``numbers`` are the doc's line numbers of ``expected`` (1, 2, ... if not given); a
    line of only ``...`` matches any number of printed lines.
    """
    numbers = list(numbers or range(1, len(expected) + 1))
    expected = _trimmed([line.rstrip() for line in expected])
    actual = _trimmed([line.rstrip() for line in actual])
    furthest = [(0, 0)]
    memo = {}

    def match(i: int, j: int) -> bool:
        if (i, j) in memo:
            return memo[i, j]
        furthest[0] = max(furthest[0], (i, j))
        if i == len(expected):
            result = j == len(actual)
        elif expected[i].strip() == '...':
            result = any(match(i + 1, k) for k in range(j, len(actual) + 1))
        else:
            result = j < len(actual) and line_matches(expected[i], actual[j], ignore) \
                and match(i + 1, j + 1)
        memo[i, j] = result
        return result

    if match(0, 0):
        return []
    i, j = furthest[0]
    want = expected[i] if i < len(expected) else '(the end of the output)'
    got = actual[j] if j < len(actual) else '(the end of the output)'
    line = numbers[min(i, len(numbers) - 1)] if numbers else 0
    return [Mismatch(str(line), want, got)]


def _trimmed(lines: list) -> list:
    while lines and not lines[-1]:
        lines = lines[:-1]
    return lines


def missing_figures(expected: list, actual: list) -> list:
    """Give the numbers with a decimal point in ``expected`` that ``actual`` never prints."""
    printed = re.findall(NUMBER, '\n'.join(actual))
    missing = []
    for offset, line in enumerate(expected):
        for number in re.findall(NUMBER, line):
            if ('.' in number or 'e' in number.lower()) and \
                    not any(same_number(number, got) for got in printed):
                missing.append((offset, number))
    return missing


@dataclass
class Session:
    """Where one doc's blocks run: what README's set-up block left (environment, folder)."""

    env: dict
    cwd: Path
    shared: bool         # whether $SHARED holds the shared data


def set_up(temp_root: Path) -> Session:
    """Run README's set-up block from the repository root; give the session it leaves."""
    steps = [block for block in read_blocks(ROOT / 'README.md') if block.mark == 'set-up']
    if len(steps) != 1:
        raise MarkError(f'README.md: {len(steps)} blocks marked docs-check: set-up, not 1')
    # The docs' nodes get a localhost-only ROS domain no test session or other check holds,
    # as the tests' do: importing the tests' conftest claims one into os.environ.
    sys.path.insert(0, str(ROOT / 'test'))
    import conftest  # noqa: F401
    state = Path(tempfile.mkdtemp(prefix='set-up-', dir=temp_root))
    script = '\n'.join(steps[0].lines) + \
        f'\npwd > {state}/pwd\nenv -0 > {state}/env\n'
    # A ROS_HOME of the doc's own: the nodes' default state files go there, so a state file
    # an earlier run left (in ~/.ros or another doc's) never changes what a doc prints.
    env = dict(os.environ, TMPDIR=str(temp_root),
               ROS_HOME=tempfile.mkdtemp(prefix='ros-home-', dir=temp_root))
    done = subprocess.run(['bash', '-e', '-c', script], cwd=ROOT, env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if done.returncode != 0:
        raise MarkError(f'{steps[0].where}: the set-up failed (exit code {done.returncode}):\n'
                        + done.stdout)
    env = dict(item.split('=', 1) for item in
               (state / 'env').read_text().split('\0') if '=' in item)
    env['PYTHONUNBUFFERED'] = '1'    # stdout and stderr in the order a terminal shows them
    shared = Path(env.get('SHARED', ''))
    if not (shared / 'data').is_dir():
        from measured_data import FLIGHT_LOGS
        shared = FLIGHT_LOGS.parent.parent
        env['SHARED'] = env['MLX_TEMPCOMP_SHARED'] = str(shared)
    return Session(env, Path((state / 'pwd').read_text().strip()), (shared / 'data').is_dir())


def run(script: str, session: Session, timeout_s: float) -> tuple:
    """Run ``script`` in bash in the session's folder; give (exit code, output lines, s)."""
    start = time.monotonic()
    process = subprocess.Popen(['bash', '-e', '-o', 'pipefail', '-c', script],
                               cwd=session.cwd, env=session.env, text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               start_new_session=True)
    try:
        output, _ = process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, 9)
        output, _ = process.communicate()
        output += f'\n(killed after {timeout_s:g} s)'
    return process.returncode, output.splitlines(), time.monotonic() - start


def _uses_shared(script: str) -> bool:
    return '$SHARED' in script or '${SHARED}' in script


def check_doc(doc: Path, temp_root: Path, report=print) -> list:
    """Run the marked blocks of ``doc`` in order; give its mismatches."""
    blocks = read_blocks(doc)
    if not any(block.mark == 'run' for block in blocks):
        return []
    session, mismatches, printed = set_up(temp_root), [], None
    for block in blocks:
        if block.mark == 'run':
            script, expected, numbers = commands_and_output(block)
            if _uses_shared(script) and not session.shared:
                report(f'{block.where}: skipped: the shared data is missing '
                       f'({session.env["SHARED"]})')
                printed = None
                continue
            code, printed, seconds = run(script, session, block.timeout_s)
            found = compare(expected, printed, block.ignore, numbers) if expected is not None \
                else []
            if code != block.exit_code:
                found.insert(0, Mismatch(str(block.line), f'exit code {block.exit_code}',
                                         f'exit code {code}; its output ends:\n    '
                                         + '\n    '.join(printed[-15:])))
        elif block.mark in ('output', 'figures') and printed is not None:
            if block.mark == 'output':
                found = compare(block.lines, printed, block.ignore,
                                range(block.line + 1, block.line + 1 + len(block.lines)))
            else:
                found = [Mismatch(str(block.line + offset), number, 'not printed')
                         for offset, number in missing_figures(block.lines, printed)]
        else:
            if block.mark == 'by hand':
                printed = None    # what follows shows its output, not the last run block's
            continue
        for mismatch in found:
            mismatch.where = f'{block.where.rpartition(":")[0]}:{mismatch.where}'
        report(f'{block.where}: {block.mark}: ' + ('ok' if not found else 'MISMATCH')
               + (f' ({seconds:.1f} s)' if block.mark == 'run' else ''))
        mismatches += found
    return mismatches


def docs() -> list:
    """Give README.md and docs/*.md."""
    return [ROOT / 'README.md'] + sorted((ROOT / 'docs').glob('*.md'))


def list_blocks(paths: list) -> None:
    """Print every command block of ``paths``: checked or by hand, and why."""
    for doc in paths:
        for block in read_blocks(doc):
            if block.mark in ('run', 'by hand'):
                script = commands_and_output(block)[0].strip().splitlines()
                status = 'checked' if block.mark == 'run' else f'by hand: {block.reason}'
                print(f'{block.where}: {status}: {script[0] if script else ""}')


def check_in_processes(paths: list, jobs: int, keep: bool) -> int:
    """
    Check each doc in a process of its own, ``jobs`` at a time; give the exit code.

    Each process claims a ROS domain of its own (set_up), so two docs' nodes never hear
    each other. A doc's report is printed whole when its process ends.
    """
    start = time.monotonic()

    def check(doc: Path) -> tuple:
        done = subprocess.run([sys.executable, __file__, str(doc)] + (['--keep'] if keep else []),
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        print(done.stdout, end='', flush=True)
        return doc, done.returncode

    with ThreadPoolExecutor(max_workers=jobs) as pool:
        codes = dict(pool.map(check, paths))
    failed = [doc.relative_to(ROOT) if doc.is_relative_to(ROOT) else doc
              for doc, code in codes.items() if code != 0]
    print(f'{len(paths)} docs in {time.monotonic() - start:.0f} s: '
          + (f'{len(failed)} failed ({", ".join(map(str, failed))})' if failed else 'all agree'))
    return max(codes.values(), default=0)


def main(argv: list = None) -> int:
    """Run the check; give the exit code (0 all agree, 1 a mismatch, 2 a bad mark)."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('docs', nargs='*', type=Path, help='default: README.md and docs/*.md')
    parser.add_argument('--list', action='store_true', help='list the blocks, run nothing')
    parser.add_argument('--keep', action='store_true', help='keep the scratch folders')
    parser.add_argument('--jobs', type=int, default=1, metavar='N',
                        help='check N docs at once, each in a process of its own (default: 1)')
    args = parser.parse_args(argv)
    paths = [path.resolve() for path in args.docs] or docs()
    try:
        if args.list:
            list_blocks(paths)
            return 0
        if args.jobs > 1 and len(paths) > 1:
            for doc in paths:
                read_blocks(doc)    # a bad mark anywhere stops it before anything runs
            return check_in_processes(paths, args.jobs, args.keep)
        temp_root = Path(tempfile.mkdtemp(prefix='docs-check-'))
        mismatches, start = [], time.monotonic()
        try:
            for doc in paths:
                mismatches += check_doc(doc, temp_root)
        finally:
            if args.keep:
                print(f'scratch folders kept in {temp_root}')
            else:
                shutil.rmtree(temp_root, ignore_errors=True)
    except MarkError as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    for mismatch in mismatches:
        print(f'{mismatch.where}: the doc shows\n    {mismatch.expected}\n  printed\n'
              f'    {mismatch.actual}')
    print(f'{len(mismatches)} mismatch(es) in {time.monotonic() - start:.0f} s')
    return 1 if mismatches else 0


if __name__ == '__main__':
    sys.exit(main())
