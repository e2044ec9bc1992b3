"""Atomic file output: write a temp file beside the target, fsync, rename.

A reader (or a crash) sees the old file or the new one, never half of one. Temp files are
named `.<target name>.<pid>-<random>.tmp<target suffix>`: the suffix keeps the format a
writer picks by it (SUMO does), and the pid lets a later run remove the leftovers of a killed
one without touching the temp files of a run still going.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

from behaviors.errors import BehaveError

T = TypeVar("T")


def temp_name_pattern(target: Path) -> re.Pattern[str]:
    """Our temp names for `target` (and the `.partial` names of populate before they were unified)."""
    name, stem, suffix = (re.escape(part) for part in (target.name, target.stem, target.suffix))
    return re.compile(rf"^\.(?:{name}\.(\d+)-[A-Za-z0-9_]+\.tmp{suffix}|{stem}\.(\d+)\.partial{suffix})$")


def temp_path(target: Path) -> Path:
    """A new, empty temp file beside `target`, in our naming pattern; the caller removes it."""
    fd, tmp = _make_temp(tempfile.mkstemp, Path(target))
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the usual permissions
    return Path(tmp)


def temp_dir(target: Path) -> Path:
    """A new temp directory beside `target` in the same naming pattern."""
    return Path(_make_temp(tempfile.mkdtemp, Path(target)))


def _make_temp(make: Callable[..., T], target: Path) -> T:
    try:
        return make(dir=target.parent, prefix=f".{target.name}.{os.getpid()}-", suffix=f".tmp{target.suffix}")
    except OSError as exc:
        raise BehaveError(f"cannot write {target}: {exc.strerror or exc}") from None


def remove_stale_temps(target: Path) -> list[Path]:
    """Delete temp files (or dirs) of `target` left by processes that no longer run; returns them."""
    target = Path(target)
    pattern = temp_name_pattern(target)
    removed = []
    with contextlib.suppress(OSError):
        for entry in os.scandir(target.parent):
            match = pattern.match(entry.name)
            if match is None or _alive(int(match.group(1) or match.group(2))):
                continue
            path = Path(entry.path)
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(path, ignore_errors=True)
            else:
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()
            removed.append(path)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # somebody else's process
        return True
    return True


def check_output_path(path: Path) -> None:
    """Fail now, before any work, if `path` cannot become an output file; clear stale temps beside it."""
    path = Path(path)
    if path.is_dir():
        raise BehaveError(f"cannot write {path}: it is a directory")
    ensure_writable_dir(path.parent)
    remove_stale_temps(path)


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """A temp path in `path`'s directory; renamed onto `path` if the block succeeds, removed if not.

    A write that fails because the disk is full becomes one BehaveError even when the writer
    (torch.save, for one) reports it as something other than an OSError.
    """
    path = Path(path)
    check_output_path(path)
    tmp = temp_path(path)
    try:
        yield tmp
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        full = isinstance(exc, Exception) and not isinstance(exc, BehaveError) and disk_full(path.parent)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise BehaveError(f"cannot write {path}: {exc.strerror or exc}") from None
        if full:
            raise BehaveError(f"cannot write {path}: No space left on device") from None
        raise


def disk_full(directory: Path) -> bool:
    """Whether the file system holding `directory` has no block left for us."""
    try:
        return os.statvfs(directory).f_bavail == 0
    except OSError:
        return False


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def ensure_writable_dir(directory: Path) -> None:
    """Create `directory` if needed; a BehaveError naming it if it cannot be written."""
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BehaveError(f"cannot create output directory {directory}: {exc.strerror}") from None
    if not os.access(directory, os.W_OK | os.X_OK):
        raise BehaveError(f"output directory {directory} is not writable")
