"""What a command may write to: never a path it did not create.

Output directories are claimed (:func:`claim_output_dir`), output files checked
(:func:`check_output_file`), and every file is written whole (:func:`atomic_file`).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import secrets
import shutil
import socket
import warnings
from collections.abc import Callable, Iterator
from datetime import datetime
from pathlib import Path
from typing import IO, Any

from tactile_compliance import __version__

try:
    import fcntl
except ImportError:  # Windows: no flock
    fcntl = None  # type: ignore[assignment]

__all__ = [
    "MARKER_NAME",
    "PARTIAL_PREFIX",
    "DirectoryLockedError",
    "OutputExistsError",
    "atomic_file",
    "check_format_version",
    "check_output_file",
    "check_output_folder",
    "claim_output_dir",
    "commit_path",
    "exchange_directories",
    "exclusive_lock",
    "fsync_directory",
    "output_kind",
    "process_alive",
    "process_start",
]

MARKER_NAME = ".tactile-compliance.json"
PARTIAL_PREFIX = ".partial-"
"""Hidden name prefix of what the generators and ``record`` write before :func:`commit_path`
(importers skip hidden directories; a re-run removes its own leftovers)."""


class OutputExistsError(FileExistsError):
    """An output path holds something this kind of command did not create."""


def process_start(pid: int) -> str | None:
    """The start time of process ``pid`` (Linux: /proc/PID/stat field 22), or None."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[-1].split()[19]
    except (OSError, IndexError):
        return None


def process_alive(pid: int, start: str | None = None) -> bool:
    """Whether process ``pid`` still runs (and is the same one, when its ``start`` is known).

    The one liveness check of the stale-lock and leftover-writer rules: a process that
    cannot be probed (someone else's, an impossible pid) counts as alive, so nothing that
    may still be in use is taken over.
    """
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError, ValueError):  # e.g. EPERM: it exists, someone else's
        return True
    current = process_start(pid)
    return start is None or current is None or current == start


def output_kind(path: str | Path) -> str | None:
    """The kind of output a directory's marker names, or None (no or unreadable marker)."""
    try:
        data = json.loads((Path(path) / MARKER_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    kind = data.get("kind") if isinstance(data, dict) else None
    return kind if isinstance(kind, str) else None


def _write_marker(path: Path, kind: str) -> None:
    # No timestamp: generated trees must be byte-identical for the same seed.
    data = {
        "kind": kind,
        "created_by": f"tactile-compliance {__version__}",
        "note": "Written by tactile-compliance: this directory may be updated by re-runs.",
    }
    with atomic_file(path / MARKER_NAME, unique=True) as handle:
        handle.write(json.dumps(data, indent=2) + "\n")


def claim_output_dir(
    path: str | Path,
    kind: str,
    *,
    recognise: Callable[[Path], bool] | None = None,
    option: str = "--out",
    create: bool = True,
) -> Path:
    """Make ``path`` the output directory of a ``kind`` command (new or empty: marked;
    marked as ``kind``: reused), or refuse.

    Args:
        kind: what writes it ("report", "experiment", "demo", ...).
        recognise: tells an unmarked directory that a concurrent command of this kind is
            creating (adopted).
        option: the command-line option that names ``path``, for the error message.
        create: False only checks (the same refusals) and creates nothing, for a command
            that must read its inputs before it may create its output.

    Raises:
        OutputExistsError: ``path`` is a file, another kind's output, or a non-empty
            directory that this kind did not create. Nothing has been written then.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} is a file, not a directory; choose another {option}")
    if out.is_dir():
        found = output_kind(out)
        if found == kind:
            return out
        if found is not None:
            raise OutputExistsError(
                f"{out} holds the output of `{found}`, not of `{kind}`; choose another {option}"
            )
        # Never adopted by its contents: no released version wrote a directory without a
        # marker.
        if any(out.iterdir()) and not (recognise is not None and recognise(out)):
            raise OutputExistsError(
                f"{out} is not empty and was not created by tactile-compliance {kind}; "
                f"nothing was changed: choose a new or empty directory for {option}"
            )
    if not create:
        return out
    out.mkdir(parents=True, exist_ok=True)
    _write_marker(out, kind)
    return out


def check_format_version(found: Any, supported: int, what: str) -> None:
    """Refuse (ValueError, one line naming both versions) a ``format_version`` other than
    the one ``supported`` version this package writes; ``what`` names the file and its
    kind ("PATH: checkpoint")."""
    if isinstance(found, bool) or not isinstance(found, int):
        raise ValueError(f"{what} format_version {found!r} is not an integer")
    if found != supported:
        kind = "newer than this package reads" if found > supported else "a pre-release format"
        raise ValueError(
            f"{what} format_version {found} is {kind}; tactile-compliance {__version__} "
            f"reads format {supported} only: "
            + ("upgrade tactile-compliance" if found > supported else "write it again")
        )


def check_output_file(
    path: str | Path, what: str, recognise: Callable[[Path], bool], option: str = "--out"
) -> Path:
    """Refuse (OutputExistsError) a symbolic link (:func:`atomic_file` never writes through
    one), a directory, or an existing file unless ``recognise`` says it is a ``what``."""
    out = Path(path)
    if out.is_symlink():
        raise OutputExistsError(
            f"{out} is a symbolic link; nothing was changed: {option} names the {what} file "
            f"itself (remove the link or choose another {option})"
        )
    if out.is_dir():
        raise OutputExistsError(f"{out} is a directory; {option} names the {what} file to write")
    if out.exists():
        try:
            ours = recognise(out)
        except Exception:  # a file we cannot even parse as ours is not ours
            ours = False
        if not ours:
            raise OutputExistsError(
                f"{out} exists and is not a {what} written by tactile-compliance; "
                f"nothing was changed: choose another {option}"
            )
    return out


def check_output_folder(path: str | Path, option: str = "--out") -> Path:
    """Refuse (OSError, one line naming ``option``) an output file whose folder does not
    exist or cannot be written: checked before the work that makes the file, so a long fit
    does not end in a failed write."""
    out = Path(path)
    folder = out.parent
    if not folder.is_dir():
        raise FileNotFoundError(f"{option} {out}: no such folder {folder}")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise PermissionError(f"{option} {out}: cannot write into {folder}")
    return out


def fsync_directory(directory: str | Path) -> None:
    """Make a rename inside ``directory`` durable (a no-op where directories can't be opened)."""
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def atomic_file(
    path: str | Path,
    mode: str = "w",
    *,
    unique: bool = False,
    encoding: str | None = None,
    before_replace: Callable[[], None] | None = None,
) -> Iterator[IO[Any]]:
    """Write ``path`` all at once: yields a temp file next to it, then fsyncs it and
    renames it over ``path``, so a reader sees the old file or the new one, never a part.
    When the block raises, the temp file is removed and ``path`` is untouched. The file's
    mode follows the umask, as with ``open()``.

    The one writer of every file a command writes. It never writes through a link: a
    symbolic link at ``path`` is refused (nothing is written), and the temp file is
    created new (``O_EXCL | O_NOFOLLOW``), so a link planted at its name is removed, never
    followed.

    Args:
        mode: ``"w"`` (text, UTF-8 unless ``encoding``) or ``"wb"`` (binary).
        unique: name the temp file ``NAME.PID.RANDOM.tmp`` instead of ``NAME.tmp``, for
            files that several processes may write at once (results-store rows).
        before_replace: called once the temp file is complete and durable, just before
            the rename: a second commit that must happen only if this file is whole
            (``record`` commits its grasp there, then the object table replaces the old).

    Raises:
        OutputExistsError: ``path`` is a symbolic link.
        OSError: the file cannot be written (its message names ``path``, not the temp
            file); a full disk keeps its ``errno`` (ENOSPC).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    path = Path(path)
    if path.is_symlink():
        raise OutputExistsError(
            f"{path} is a symbolic link; nothing was written through it: remove the link "
            f"or choose another path"
        )
    suffix = f".{os.getpid()}.{secrets.token_hex(4)}.tmp" if unique else ".tmp"
    tmp = path.with_name(path.name + suffix)
    if mode == "w" and encoding is None:
        encoding = "utf-8"
    if not unique and os.path.lexists(tmp) and not tmp.is_dir():
        # A killed writer's leftover, or a link planted at the temp name: removed (an
        # unlink removes a link itself, never its target).
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    try:
        handle = open(tmp, mode, encoding=encoding, opener=_exclusive_opener)  # noqa: SIM115
    except OSError as err:
        raise _write_error(err, path) from None
    try:
        with handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        if before_replace is not None:
            before_replace()
        os.replace(tmp, path)
    except BaseException as err:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if (
            isinstance(err, OSError)
            and err.errno in _WRITE_ERRNOS
            and str(path) not in str(err)
            and tmp.name not in str(err)
        ):
            # A full disk while this file was written: say which file (the errno stays).
            raise OSError(err.errno, f"cannot write {path}: {err.strerror or err}") from err
        raise
    fsync_directory(path.parent)


#: The errors of a write that found no room (a full disk, a quota, a file-size limit) or
#: failed on the device: :func:`atomic_file` names its file in their message.
_WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EIO})


_NO_FOLLOW = getattr(os, "O_NOFOLLOW", 0)


def _exclusive_opener(name: str, flags: int) -> int:
    """``open()``'s opener for :func:`atomic_file`'s temp file: created new, not a link."""
    return os.open(name, flags | os.O_CREAT | os.O_EXCL | _NO_FOLLOW, 0o666)


def _write_error(err: OSError, path: Path) -> OSError:
    """``err`` (opening the temp file of ``path``) as one line naming ``path``."""
    if err.errno == errno.ENOENT:
        reason = f"no such folder {path.parent}"
    elif err.errno in (errno.EEXIST, errno.ELOOP):
        reason = "another process is writing it (its temp file exists)"
    else:
        reason = err.strerror or str(err)
    return type(err)(err.errno, f"cannot write {path}: {reason}")


def commit_path(partial: str | Path, final: str | Path, *, replace: bool = False) -> None:
    """Rename a finished temporary directory (or file) ``partial``, a hidden sibling of
    ``final``, to ``final``: the one atomic commit of the store, the generators and
    ``record``.

    Args:
        replace: an existing ``final`` is moved aside (``.NAME.old-PID-RANDOM``), replaced
            and then deleted; if the second rename fails it is put back.

    Raises:
        FileExistsError: ``final`` exists and ``replace`` is False (``partial`` is left
            for the caller to remove).
        OSError: a rename failed; ``final`` is as it was.
    """
    partial, final = Path(partial), Path(final)
    if not os.path.lexists(final):
        os.rename(partial, final)
    elif not replace:
        raise FileExistsError(f"{final} already exists; nothing was overwritten")
    else:
        aside = final.with_name(f".{final.name}.old-{os.getpid()}-{secrets.token_hex(4)}")
        os.replace(final, aside)
        try:
            os.replace(partial, final)
        except OSError:
            os.replace(aside, final)  # the old one goes back
            raise
        if aside.is_dir() and not aside.is_symlink():
            shutil.rmtree(aside, ignore_errors=True)
        else:
            aside.unlink(missing_ok=True)
    fsync_directory(final.parent)


def exchange_directories(first: str | Path, second: str | Path) -> None:
    """Swap two directories' names at once (Linux ``renameat2(RENAME_EXCHANGE)``); elsewhere
    two renames, where a kill between them leaves ``first`` as a hidden ``.NAME.old-PID``."""
    first, second = Path(first), Path(second)
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        renameat2 = None
    if renameat2 is not None:
        at_fdcwd, rename_exchange, names = -100, 2, (os.fsencode(first), os.fsencode(second))
        if renameat2(at_fdcwd, names[0], at_fdcwd, names[1], rename_exchange) == 0:
            fsync_directory(first.parent)
            return
        code = ctypes.get_errno()
        if code not in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP):
            raise OSError(code, os.strerror(code), str(first))
    aside = first.with_name(f".{first.name}.old-{os.getpid()}")
    os.rename(first, aside)
    os.rename(second, first)
    os.rename(aside, second)
    fsync_directory(first.parent)


class DirectoryLockedError(OSError):
    """Another process holds a lock taken with ``wait=False`` (see :func:`exclusive_lock`)."""


def _holder_record() -> str:
    since = datetime.now().astimezone().isoformat(timespec="seconds")
    return f"pid {os.getpid()} on {socket.gethostname()} since {since}"


def _held_by_other_process(record: str) -> bool:
    """For file systems without ``flock``: whether ``record`` names a live other process."""
    match = re.match(r"pid (\d+) on (\S+)", record)
    if match is None:
        return False
    pid, host = int(match.group(1)), match.group(2)
    if host != socket.gethostname():
        return True  # cannot tell from here: treat as held (the message says what to do)
    return pid != os.getpid() and process_alive(pid)


@contextlib.contextmanager
def exclusive_lock(
    path: str | Path, what: str = "this directory", *, wait: bool = True
) -> Iterator[Path]:
    """Hold an exclusive ``flock`` on the file ``path`` (created if needed): the one lock.

    The file records its holder (``pid PID on HOST since TIME``) while it is held. The
    kernel releases the lock when its holder dies, however it dies, so a lock file left by
    a killed process is simply taken over. It is never deleted: unlinking it while another
    process waits on the old inode would let a third process lock a new file and enter at
    the same time.

    Args:
        what: what the lock protects, for the messages ("the feature cache").
        wait: True waits until the lock is free (short sections several processes may
            enter); False fails at once (a run directory: a second process is a mistake).
            Without ``flock``, a waiting lock runs unlocked with a warning and a
            non-waiting one lets the recorded PID decide.

    Raises:
        DirectoryLockedError: ``wait=False`` and another process holds the lock.
    """
    path = Path(path)
    busy = (
        f"{path.parent} is in use: its lock {path} is held by {{}}; wait for that process "
        f"to finish or use another {what}"
    )
    with open(path, "a+", encoding="utf-8") as handle:
        locked = fcntl is not None
        if fcntl is not None:
            try:
                fcntl.flock(handle.fileno(), fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
            except OSError as err:
                if err.errno not in (errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOLCK):
                    handle.seek(0)
                    raise DirectoryLockedError(
                        busy.format(handle.read().strip() or "another process")
                    ) from None
                locked = False
        if not locked and wait:
            # Some cluster file systems (Lustre mounted without -o flock) refuse locks.
            warnings.warn(
                f"{path.parent}: the file system does not support flock; writing {what} "
                f"without a lock (do not write it from two processes)",
                stacklevel=3,
            )
        elif not locked:  # no flock here: fall back to the recorded PID
            handle.seek(0)
            holder = handle.read().strip()
            if holder and _held_by_other_process(holder):
                raise DirectoryLockedError(
                    busy.format(holder) + " (delete the lock file if that process is gone)"
                )
        handle.seek(0)
        handle.truncate()
        handle.write(_holder_record() + "\n")
        handle.flush()
        try:
            yield path
        finally:
            # Released: an empty file names nobody (a killed holder leaves its record).
            with contextlib.suppress(OSError):
                handle.seek(0)
                handle.truncate()
                handle.flush()
