"""
A command's outputs, written whole or not at all: staged beside their targets, renamed in.

`staged_outputs` gives an `Outputs` for one command run. Each output (a
file, a folder, a bag folder its writer creates) is written under a staging
name beside its target, in the same folder (a rename is atomic only within
one file system) and hidden: ``.<name>.<random>.partial``; a folder its writer
creates (a bag, which names its files after its folder) is written under
its own name inside such a hidden folder, which goes once it is renamed out. An output whose
target lies in a folder staged in the same run is written straight into that
staging folder and moves with it. When the run ends normally, every target
is replaced by its staged output: a previous folder is renamed aside first, a
previous file kept by a hard link, both removed once all are in place; if a
rename fails, those done are undone. When the run ends by an exception
(an error, Ctrl-C), the staged outputs are removed and the targets are left
as they were. Ctrl-C during the renames is held until they are done. Only a
kill (SIGKILL, power loss) can leave a ``.partial`` or ``.old`` name behind.
`fleet` stores each unit's folder this way too.
"""

import contextlib
import errno
import os
from pathlib import Path
import shutil
import signal
import threading
import uuid


def _hidden(target: Path, suffix: str) -> Path:
    return target.with_name(f'.{target.name}.{uuid.uuid4().hex[:8]}.{suffix}')


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _linked(path: Path, link: Path) -> bool:
    """Hard-link ``link`` to ``path``; False where the file system has no hard links."""
    try:
        os.link(path, link)
    except OSError:
        return False
    return True


@contextlib.contextmanager
def _interrupt_held():
    """Hold Ctrl-C (SIGINT) until the block is done, then raise it; main thread only."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield
        return
    caught = []
    previous = signal.signal(signal.SIGINT, lambda *_: caught.append(True))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


class Outputs:
    """The outputs of one command run: staging paths now, the targets at `commit`."""

    def __init__(self):
        # (staging path, target, replace: whether a previous target may be replaced)
        self.pending = []
        # Hidden folders holding a staged output under its own name, removed at the end.
        self.holders = []

    def _in_staged_folder(self, target: Path):
        for staging, folder, _ in self.pending:
            if staging.is_dir() and target.parent == folder:
                return staging / target.name
        return None

    def file(self, target) -> Path:
        """Give the path to write file ``target`` to (not created)."""
        target = Path(os.path.abspath(target))
        inside = self._in_staged_folder(target)
        if inside is not None:
            return inside
        staging = _hidden(target, 'partial')
        self.pending.append((staging, target, True))
        return staging

    def folder(self, target, create: bool = True, replace: bool = True) -> Path:
        """
        Give the folder to write ``target``'s files into.

        ``create`` False leaves it to the writer to create (a rosbag2 writer
        refuses an existing folder); ``replace`` False refuses, at the commit,
        a target that exists by then.
        """
        target = Path(os.path.abspath(target))
        inside = self._in_staged_folder(target)
        if inside is not None:
            if create:
                inside.mkdir()
            return inside
        staging = _hidden(target, 'partial')
        staging.mkdir()
        if not create:   # the writer creates it, named as the target
            self.holders.append(staging)
            staging = staging / target.name
        self.pending.append((staging, target, replace))
        return staging

    def discard(self) -> None:
        """Remove every staged output; the targets stay as they were."""
        for staging, _, _ in self.pending:
            _remove(staging)
        self.pending = []
        self._remove_holders()

    def _remove_holders(self) -> None:
        for holder in self.holders:
            _remove(holder)
        self.holders = []

    def commit(self) -> None:
        """Put every staged output in its target's place, all or none (OSError if none)."""
        done = []
        with _interrupt_held():
            try:
                for staging, target, replace in self.pending:
                    done.append((target, self._swap(staging, target, replace)))
            except BaseException:
                for target, kept in reversed(done):
                    _remove(target)
                    if kept is not None:
                        os.replace(kept, target)
                self.discard()
                raise
        self.pending = []
        self._remove_holders()
        for _, kept in done:
            if kept is not None:
                _remove(kept)

    @staticmethod
    def _swap(staging: Path, target: Path, replace: bool):
        """Rename ``staging`` to ``target``; give where the previous target is kept, or None."""
        if not (target.exists() or target.is_symlink()):
            os.rename(staging, target)
            return None
        if not replace:
            raise FileExistsError(errno.EEXIST, 'it appeared while the command ran', str(target))
        if target.is_dir() != staging.is_dir():   # never a folder for a file, nor the reverse
            kind = IsADirectoryError if target.is_dir() else NotADirectoryError
            raise kind(errno.EISDIR if target.is_dir() else errno.ENOTDIR,
                       'a folder and a file cannot replace each other', str(target))
        kept = _hidden(target, 'old')
        if not staging.is_dir() and _linked(target, kept):
            try:
                os.replace(staging, target)   # the old file stays reachable as ``kept``
            except BaseException:
                kept.unlink()
                raise
            return kept
        os.rename(target, kept)
        try:
            os.rename(staging, target)
        except BaseException:
            os.rename(kept, target)
            raise
        return kept


@contextlib.contextmanager
def staged_outputs():
    """Give an `Outputs`; commit it when the block ends normally, discard it otherwise."""
    outputs = Outputs()
    try:
        yield outputs
    except BaseException:
        outputs.discard()
        raise
    outputs.commit()
