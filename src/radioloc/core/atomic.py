"""Atomic output: a file or a folder is either the complete new version or not there.

Files are written to a temporary name in the same folder, flushed to disk and renamed over
the target with :func:`os.replace` (atomic on POSIX and Windows). A reader, or a run that
is interrupted (Ctrl-C, a full disk, a kill), therefore sees the previous complete file
or the new complete file, never a partial one.

Folders (one experiment's results of ``radioloc reproduce``) are built in a staging folder
``OUT/.radioloc-staging/<name>-<pid>-<token>`` beside the target and swapped in at the
end with one rename (``renameat2(RENAME_EXCHANGE)`` on Linux, so the target is never
missing; elsewhere two renames, so that for an instant the target is absent but never
mixed). Staging folders left by a killed process are removed by the next run.

An output never destroys data it was not asked to replace: a write-protected file is
refused, not replaced (:func:`check_output_file`); the temporary file of a write killed
before its rename (``.<name>.tmp-<pid>-<token>``) is removed by the next write in that
folder; and :func:`check_outputs` refuses an output that names one of the command's
inputs or another of its outputs.

Every :class:`OSError` is turned into :class:`~radioloc.core.errors.OutputError` naming the
path and the reason in words.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import os
import re
import secrets
import shutil
import stat
from pathlib import Path
from typing import IO, Callable, Iterator

from radioloc.core.errors import OutputError

STAGING = ".radioloc-staging"

_REASONS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.EISDIR: "it is a folder, not a file",
    errno.ENOTDIR: "a part of the path is a file, not a folder",
    errno.ENOENT: "the folder does not exist",
    errno.ENAMETOOLONG: "the name is too long",
    errno.EEXIST: "a file of that name is in the way",
}


def describe_os_error(exc: OSError) -> str:
    """The reason of an :class:`OSError` in words, without the Python class name."""
    if exc.errno in _REASONS:
        return _REASONS[exc.errno]
    return exc.strerror or str(exc) or type(exc).__name__


def output_error(path: Path | str, exc: OSError, what: str = "cannot write") -> OutputError:
    """An :class:`OutputError` ``"<path>: cannot write (<reason>)"``."""
    return OutputError(f"{path}: {what} ({describe_os_error(exc)})")


def check_output_file(path: Path | str) -> Path:
    """Refuse, before any work, an output file path that cannot be a file.

    Parameters
    ----------
    path : path
        Where a file will be written.

    Returns
    -------
    Path
        ``path`` as a :class:`~pathlib.Path`.

    Raises
    ------
    OutputError
        ``path`` is an existing folder, one of its parents is an existing file, or it is
        an existing file that is write-protected (no write permission for anyone, or none
        for this user): it is refused, never replaced.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: cannot write (it is a folder, not a file; give a file name)")
    check_folder_path(path.parent, what=str(path))
    if _write_protected(path):
        raise OutputError(f"{path}: cannot write (the file is write-protected; make it "
                          "writable or give another name)")
    return path


def _write_protected(path: Path) -> bool:
    """An existing regular file without write permission (for anyone, or for this user)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return stat.S_ISREG(mode) and (not mode & 0o222 or not os.access(path, os.W_OK))


def _same_file(a: Path, b: Path) -> bool:
    """``a`` and ``b`` are one file: the same existing file (through links too) or the
    same resolved path."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def check_outputs(outputs: list[tuple[str, Path | str | None]],
                  inputs: list[tuple[str, Path | str | None]] = ()) -> None:
    """Refuse, before any is written, outputs that cannot be written
    (:func:`check_output_file`) or would replace an input or another output of the same
    command.

    Parameters
    ----------
    outputs : list of (name, path)
        The files a command will write, each with the name the message uses (``"--out"``,
        ``"--plot"``, ``"the summary"``); a None path, ``-`` or a device is skipped.
    inputs : list of (name, path)
        The files it reads (None skipped).

    Returns
    -------
    None

    Raises
    ------
    OutputError
        An output cannot be written, is one of the inputs, or two outputs are one file
        (hard and symbolic links included).
    """
    def files(pairs):
        return [(name, Path(p)) for name, p in pairs
                if p is not None and str(p) != "-" and not _is_special(Path(p))]

    outs, ins = files(outputs), files(inputs)
    for i, (name, path) in enumerate(outs):
        check_output_file(path)
        for other, o_path in ins + outs[:i]:
            if _same_file(path, o_path):
                raise OutputError(f"{name} {path}: is also {other} ({o_path}) and would replace "
                                  "it; give another name")


def check_folder_path(folder: Path | str, *, what: str | None = None) -> Path:
    """Refuse a folder path whose nearest existing part is a file.

    Parameters
    ----------
    folder : path
        A folder that will be created if missing.
    what : str, optional
        The path to name in the message (default: ``folder``).

    Returns
    -------
    Path
        ``folder`` as a :class:`~pathlib.Path`.

    Raises
    ------
    OutputError
        ``folder`` or one of its parents is an existing file.
    """
    folder = Path(folder)
    for part in (folder, *folder.parents):
        if part.exists():
            if not part.is_dir():
                raise OutputError(f"{what or folder}: cannot write ({part} is a file, not a folder)")
            break
    return folder


def _is_special(path: Path) -> bool:
    """An existing target that is not a regular file (a device such as /dev/null or
    /dev/full, a pipe, a terminal): it is written in place, never replaced."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not stat.S_ISREG(mode) and not stat.S_ISDIR(mode)


@contextlib.contextmanager
def atomic_open(path: Path | str, mode: str = "w", *, encoding: str | None = "utf-8",
                newline: str | None = None) -> Iterator[IO]:
    """Open a temporary file beside ``path``; on success it replaces ``path`` atomically.

    Parameters
    ----------
    path : path
        The target file. Its folder is created if missing. A device or pipe (e.g.
        ``/dev/stdout``) is written in place instead.
    mode : {"w", "wb"}
        Text or binary.
    encoding, newline : str, optional
        As for :func:`open` (text mode only).

    Returns
    -------
    context manager yielding the open file object
        On an exception inside the ``with`` block (including ``KeyboardInterrupt``) the
        temporary file is removed and ``path`` is left as it was.

    Raises
    ------
    OutputError
        The file cannot be written (folder in the way, permission, full device, ...).
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open: mode must be 'w' or 'wb', got {mode!r}")
    path = Path(path)
    kw = {} if "b" in mode else {"encoding": encoding, "newline": newline}
    if _is_special(path):
        try:
            with open(path, mode, **kw) as fh:
                yield fh
        except OSError as exc:
            raise output_error(path, exc) from None
        return
    check_output_file(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(path.parent)
        fh = open(tmp, mode.replace("w", "x"), **kw)
    except OSError as exc:
        raise output_error(path, exc) from None
    try:
        try:
            with fh:
                yield fh
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except OSError as exc:
            raise output_error(path, exc) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def atomic_write_text(path: Path | str, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (UTF-8); see :func:`atomic_open`.

    Parameters
    ----------
    path : path
        Target file.
    text : str
        Its complete content.

    Returns
    -------
    Path
        ``path``.
    """
    with atomic_open(path, "w") as fh:
        fh.write(text)
    return Path(path)


def atomic_write_with(path: Path | str, writer: Callable[[IO], object], *, binary: bool = False
                      ) -> Path:
    """Call ``writer(file)`` on a temporary file that then atomically replaces ``path``.

    Parameters
    ----------
    path : path
        Target file.
    writer : callable
        Receives the open file object, e.g. ``lambda f: frame.to_csv(f, index=False)``.
    binary : bool
        Open in binary mode.

    Returns
    -------
    Path
        ``path``.
    """
    with atomic_open(path, "wb" if binary else "w", newline=None if binary else "") as fh:
        writer(fh)
    return Path(path)


#: The name of a temporary file of :func:`atomic_open`: ``.<target>.tmp-<pid>-<token>``.
_TEMPORARY = re.compile(r"\..+\.tmp-(\d+)-[0-9a-f]{8}")


def remove_stale_temporaries(folder: Path | str) -> None:
    """Remove the temporary files of :func:`atomic_open` in ``folder`` whose process is gone
    (a write killed before its rename).

    Parameters
    ----------
    folder : path

    Returns
    -------
    None
    """
    try:
        names = os.listdir(folder)
    except OSError:
        return
    for name in names:
        match = _TEMPORARY.fullmatch(name)
        if match and not _pid_alive(int(match.group(1))):
            with contextlib.suppress(OSError):
                os.unlink(Path(folder) / name)


# ---- folders --------------------------------------------------------------------------

def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def remove_stale_staging(parent: Path | str) -> None:
    """Remove staging folders under ``parent/.radioloc-staging`` whose process is gone.

    Parameters
    ----------
    parent : path
        The output root (``--out``).

    Returns
    -------
    None
    """
    root = Path(parent) / STAGING
    if not root.is_dir():
        return
    for entry in root.iterdir():
        try:
            pid = int(entry.name.rsplit("-", 2)[-2])
        except (ValueError, IndexError):
            pid = -1
        if pid < 0 or not _pid_alive(pid):
            shutil.rmtree(entry, ignore_errors=True)
    with contextlib.suppress(OSError):
        root.rmdir()  # only if empty


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100
_libc = None


def _exchange(a: Path, b: Path) -> bool:
    """Atomically swap two existing paths (Linux ``renameat2``); False if unsupported."""
    global _libc
    if not hasattr(os, "fork") or os.uname().sysname != "Linux":
        return False
    try:
        if _libc is None:
            _libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        fn = _libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


@contextlib.contextmanager
def staged_folder(target: Path | str) -> Iterator[Path]:
    """Build a folder in a staging place; on success it replaces ``target`` as a whole.

    Parameters
    ----------
    target : path
        The folder to produce (e.g. ``out/<experiment id>``). Its previous content, if
        any, is replaced as a whole: nothing of an earlier run survives beside the new one.

    Returns
    -------
    context manager yielding the staging folder (empty) to write into
        On an exception inside the ``with`` block (including ``KeyboardInterrupt``) the
        staging folder is removed and ``target`` keeps the previous complete run.

    Raises
    ------
    OutputError
        The output root cannot be created or written, or ``target`` is a file.
    """
    target = Path(target)
    parent = target.parent
    try:
        if target.exists() and not target.is_dir():
            raise OutputError(f"{target}: cannot write (it is a file, not a folder)")
        check_folder_path(parent)
        parent.mkdir(parents=True, exist_ok=True)
        remove_stale_staging(parent)
        token = secrets.token_hex(4)
        stage_root = parent / STAGING
        stage_root.mkdir(exist_ok=True)
        stage = stage_root / f"{target.name}-{os.getpid()}-{token}"
        stage.mkdir()
    except OSError as exc:
        raise output_error(parent, exc) from None
    try:
        yield stage
        try:
            if target.exists():
                if not _exchange(stage, target):
                    old = stage_root / f"{target.name}.old-{os.getpid()}-{token}"
                    os.replace(target, old)
                    os.replace(stage, target)
                # after an exchange, ``stage`` holds the previous run
            else:
                os.replace(stage, target)
        except OSError as exc:
            raise output_error(target, exc) from None
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    finally:
        for leftover in (stage, stage_root / f"{target.name}.old-{os.getpid()}-{token}"):
            if leftover.exists():
                shutil.rmtree(leftover, ignore_errors=True)
        with contextlib.suppress(OSError):
            stage_root.rmdir()
