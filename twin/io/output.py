"""The output contract of every command that writes files.

1. **Check before working.** :func:`check_output_folder` and :func:`check_output_file` refuse a
   bad location (an existing file where a folder goes, an existing folder without ``force``, a
   parent that is a file, a folder that cannot be written) in one line, before any simulation.
2. **Stage, then move into place.** :class:`Staged` writes everything into a hidden temporary
   folder beside the target (``.NAME.partial-XXXXXX``) and, for a file outside the folder
   (``--rrd`` elsewhere), a hidden temporary file beside it (``.STEM.partial-XXXXXX.rrd``).
   :meth:`Staged.commit` moves the outside files into place and then the folder, replacing an
   existing one whole (``force``):
   old and new files never mix, and a folder that exists under the target's name is complete.
3. **Nothing left behind.** Leaving the ``with`` block without :meth:`Staged.commit` (an error, an
   interrupt, SIGTERM: the command line turns it into an exception) removes every temporary.
4. **An interrupted command commits nothing.** The command line notes each SIGINT/SIGTERM here
   (:func:`note_signal`) as well as raising it; a library can swallow the raised exception (a
   signal landing while a compiled module is imported, or inside a callback), so every commit
   and every result printed first calls :func:`raise_if_interrupted`.
5. **A colleague can read the results.** Folders and files are given the permissions a new
   folder or file gets under the user's umask (the temporaries' private 0700/0600 are not kept).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from types import TracebackType

from twin.errors import TwinError

__all__ = ["PARTIAL_MARK", "Interrupted", "Staged", "check_output_file", "check_output_folder", "clear_committed",
           "clear_signal", "committed", "new_file_mode", "new_folder_mode", "note_signal", "raise_if_interrupted",
           "signal_received"]

#: Part of the name of every temporary folder or file (hidden, beside the target).
PARTIAL_MARK = ".partial-"


class Interrupted(Exception):
    """A signal was received, but the exception it raised was swallowed by a library."""


_signal: list[int] = []  # the first SIGINT/SIGTERM the command received, if any


def note_signal(signum: int) -> None:
    """Remember a received signal (the first one counts)."""
    if not _signal:
        _signal.append(int(signum))


def signal_received() -> int | None:
    """The first signal received since :func:`clear_signal`, or None."""
    return _signal[0] if _signal else None


def clear_signal() -> None:
    _signal.clear()


_committed: list[Path] = []  # the outputs this command has put in place


def committed() -> list[Path]:
    """The outputs put in place (by :meth:`Staged.commit`) since :func:`clear_committed`."""
    return list(_committed)


def clear_committed() -> None:
    _committed.clear()


def raise_if_interrupted() -> None:
    """Raise :class:`Interrupted` when a signal has been received: nothing may be committed or
    printed as a result after it."""
    if _signal:
        raise Interrupted(f"signal {_signal[0]} received")


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


def new_file_mode() -> int:
    """The permissions of a new file under the user's umask (mkstemp makes files 0600)."""
    return 0o666 & ~_umask()


def new_folder_mode() -> int:
    """The permissions of a new folder under the user's umask (mkdtemp makes folders 0700)."""
    return 0o777 & ~_umask()


def _existing_ancestor(path: Path) -> Path:
    p = path.absolute().parent
    while not p.exists():
        p = p.parent
    return p


def _check_parent(path: Path, option: str) -> None:
    """The nearest existing ancestor of ``path`` must be a folder we can write into."""
    anc = _existing_ancestor(path)
    if not anc.is_dir():
        raise TwinError(f"{option} {path}: {anc} is a file, not a folder")
    if not os.access(anc, os.W_OK | os.X_OK):
        raise TwinError(f"{option} {path}: folder {anc} is not writable")


def check_output_folder(path: str | Path, force: bool, option: str = "--out") -> Path:
    """Refuse an output folder that cannot be (re)written; returns it as a Path.

    Allowed: a path that does not exist (its parents are created), or an existing folder
    when ``force`` (it is replaced whole at the end).
    """
    out = Path(path)
    if str(path).strip() == "":
        raise TwinError(f"{option} must name a folder, got an empty path")
    if out.exists() or out.is_symlink():
        if not out.is_dir():
            raise TwinError(f"{option} {out} exists and is not a folder")
        if not force:
            raise TwinError(f"{option} {out} exists; choose a new folder or pass --force to replace it whole")
        if not os.access(out.absolute().parent, os.W_OK | os.X_OK):
            raise TwinError(f"{option} {out}: its parent folder is not writable, so it cannot be replaced")
    _check_parent(out, option)
    return out


def check_output_file(path: str | Path, suffix: str, force: bool, option: str) -> Path:
    """Refuse an output file with the wrong suffix, in a folder that cannot be written, or that
    exists (unless ``force``); returns it as a Path."""
    p = Path(path)
    if p.suffix.lower() != suffix:
        raise TwinError(f"{option} must name a {suffix} file, got {str(path)!r}")
    if p.is_dir():
        raise TwinError(f"{option} {p} is a folder; give a {suffix} file")
    if p.exists() and not force:
        raise TwinError(f"{option} {p} exists; choose a new file or pass --force to replace it")
    _check_parent(p, option)
    return p


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.absolute().relative_to(folder.absolute())
    except ValueError:
        return False
    return True


class Staged:
    """A staged output folder (and outside files), moved into place by :meth:`commit` only.

    Use::

        with Staged(out_dir) as stage:
            rrd_tmp = stage.file(rrd_path)      # where to write the recording now
            write(stage.folder / "report.json")
            stage.commit()

    The locations must have been checked (:func:`check_output_folder`, :func:`check_output_file`).
    """

    def __init__(self, out: Path):
        self.out = Path(out)
        self.folder: Path = Path()
        self._files: list[tuple[Path, Path]] = []  # (temporary, target) outside the folder
        self._committed = False

    def __enter__(self) -> Staged:
        self.out.absolute().parent.mkdir(parents=True, exist_ok=True)
        self.folder = Path(tempfile.mkdtemp(prefix=f".{self.out.name}{PARTIAL_MARK}", dir=self.out.absolute().parent))
        return self

    def file(self, target: Path) -> Path:
        """Where to write ``target`` now: inside the staged folder if ``target`` lies in the
        output folder, else a hidden temporary beside it (moved into place by :meth:`commit`)."""
        target = Path(target)
        if _inside(target, self.out):
            staged = self.folder / target.absolute().relative_to(self.out.absolute())
            staged.parent.mkdir(parents=True, exist_ok=True)
            return staged
        target.absolute().parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f".{target.stem}{PARTIAL_MARK}", suffix=target.suffix,
                                   dir=target.absolute().parent)
        os.fchmod(fd, new_file_mode())
        os.close(fd)
        self._files.append((Path(name), target))
        return Path(name)

    def commit(self) -> Path:
        """Move the outside files, then the folder, into place (an existing folder is replaced);
        refused (:class:`Interrupted`) once a signal has been received."""
        raise_if_interrupted()
        os.chmod(self.folder, new_folder_mode())
        for tmp, target in self._files:
            os.replace(tmp, target)
        old = None
        if self.out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.old-", dir=self.out.absolute().parent))
            os.replace(self.out, old / self.out.name)
        os.replace(self.folder, self.out)
        self._committed = True
        _committed.extend([*(target for _, target in self._files), self.out])
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return self.out

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._committed:
            return
        shutil.rmtree(self.folder, ignore_errors=True)
        for tmp, _ in self._files:
            tmp.unlink(missing_ok=True)
