"""Crash-safe output: every result file appears whole or not at all.

Files are first written into a hidden staging folder beside the target folder
and moved into place with `os.replace` (atomic on POSIX) only once everything
has been written, so a run killed midway leaves no half-written result. A full
disk (ENOSPC, EDQUOT) while writing is a `DiskFullError` naming the folder, and
one process at a time writes a folder (`folder_lock`, an advisory lock).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from jaxeac.errors import UsageError


def check_out_path(path: str | os.PathLike, flag: str = "--out") -> Path:
    """An output folder name that names a folder: not empty, no NUL byte (nothing is created)."""
    text = os.fspath(path)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    if not text.strip():
        raise UsageError(f"{flag} is empty; name a folder for the results, e.g. {flag} runs/mine")
    if "\0" in text:
        raise UsageError(f"{flag} {text!r} contains a NUL byte; name a folder without one")
    try:
        os.stat(text)
    except (FileNotFoundError, NotADirectoryError):
        pass
    except OSError as exc:  # a name too long, a loop of links, no permission to look
        raise UsageError(f"{flag} {text}: {exc.strerror or exc}; choose another folder") from None
    return Path(text)


def check_writable_dir(path: str | os.PathLike) -> Path:
    """Create `path` if needed and check that files can be written there."""
    out = check_out_path(path)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} exists and is not a directory; choose another path")
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out, prefix=".probe-"):
            pass
    except OSError as exc:
        reason = exc.strerror or exc
        raise UsageError(f"cannot write to --out {out}: {reason}; choose a writable folder") from None
    return out


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write `data` to `path` through a temporary file and a rename."""
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        if is_disk_full(exc):
            raise disk_full_error(exc, path) from exc
        raise
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if is_disk_full(exc):
            raise disk_full_error(exc, path) from exc
        raise


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write `text` (UTF-8) to `path` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays and paths so `json.dumps` accepts them."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def atomic_write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write `obj` as pretty JSON atomically (NaN/inf become null)."""
    atomic_write_text(path, json.dumps(to_jsonable(obj), indent=2, sort_keys=False) + "\n")


#: The files a run folder's writer owns: a new run into a folder replaces all of them, so a
#: folder never mixes one run's results with another run's report or figures.
RUN_FOLDER_FILES = ("summary.json", "results.parquet", "per_seed.csv", "curves.npz", "policies.npz",
                    "bowling.npz", "table1.md", "fig*.png", "stats.json", "report.md", "compare_*.png")


FOLDER_KINDS = {"run": "a grid or bowling run", "sweep": "a sweep", "reproduce": "a reproduction",
                "study": "a study"}


def folder_kind(path: str | os.PathLike) -> tuple[str, Path] | None:
    """(kind, the file that says so) of what an existing output folder holds, or None: a
    reproduction (``reproduce.json`` in it or in a step folder), a study (``study.json``, or
    task folders under ``tasks/``), a sweep (``sweep.json``) or a run (``summary.json``)."""
    path = Path(path)
    try:
        if not path.is_dir():
            return None
        markers = [("reproduce", path / "reproduce.json"), ("study", path / "study.json"),
                   ("sweep", path / "sweep.json"), ("run", path / "summary.json")]
        markers[2:2] = [("study", task) for task in sorted(path.glob("tasks/*/summary.json"))[:1]]
        markers[1:1] = [("reproduce", step) for step in sorted(path.glob("*/reproduce.json"))]
        return next(((kind, marker) for kind, marker in markers if marker.is_file()), None)
    except OSError:  # a name too long, a folder that cannot be listed: `check_writable_dir` says so
        return None


def check_folder_kind(path: str | os.PathLike, kind: str, *, reads: bool = False) -> None:
    """Refuse a folder that holds another kind of output than `kind`: to write into (their files
    would mix: a run replaces only a run's files, a sweep or a reproduction resumes its own), or
    to read as one (`reads`: compare, merge)."""
    found = folder_kind(path)
    if found is not None and found[0] != kind:
        fix = (f"pass a folder holding {FOLDER_KINDS[kind]}" if reads
               else "choose another --out (a new or empty folder)")
        raise UsageError(f"{path} holds {FOLDER_KINDS[found[0]]} ({found[1]}), "
                         f"not {FOLDER_KINDS[kind]}; {fix}")


_STAGES: dict[str, int] = {}  # real path of an output folder -> stages of this process open in it


@contextlib.contextmanager
def staged_dir(out: str | os.PathLike, replaces: tuple[str, ...] = ()) -> Iterator[Path]:
    """Yield a staging folder; on success move its files into `out`, else delete it.

    Files of `out` matching a pattern of `replaces` that the stage did not write are
    removed once the new files are in place (a new run replaces the old one as a whole).

    Usage::

        with staged_dir(out) as stage:
            np.savez(stage / "curves.npz", ...)
            (stage / "per_seed.csv").write_text(...)
        # all files now in `out`; if the block raised, `out` is untouched
    """
    with folder_lock(out):
        out = check_writable_dir(out)
        key = os.path.realpath(out)
        if not _STAGES.get(key):  # no stage of ours is open here: any is left by a killed run
            _remove_stale_stages(out)
        others = set(out.glob(".staging-*"))  # an enclosing stage of this folder, if any
        _STAGES[key] = _STAGES.get(key, 0) + 1
        try:
            stage = Path(tempfile.mkdtemp(dir=out, prefix=".staging-"))
            yield stage
            written = {item.name for item in stage.iterdir()}
            for item in sorted(stage.iterdir()):
                os.replace(item, out / item.name)
            for pattern in replaces:
                for old in out.glob(pattern):
                    if old.is_file() and old.name not in written:
                        old.unlink()
        except Exception as exc:  # an OSError, or a library's error raised from one
            if is_disk_full(exc):
                raise disk_full_error(exc, out) from exc
            raise
        finally:  # this stage, also if a Ctrl-C came before it had a name (we hold the folder's lock)
            _STAGES[key] -= 1
            for stage in set(out.glob(".staging-*")) - others:
                shutil.rmtree(stage, ignore_errors=True)


def _remove_stale_stages(out: Path) -> None:
    """Remove the staging folders and write probes in `out`, a folder this process holds with no
    stage of its own open there: any such file is left by a killed or interrupted run."""
    for stale in out.glob(".staging-*"):
        shutil.rmtree(stale, ignore_errors=True)
    for probe in out.glob(".probe-*"):
        with contextlib.suppress(OSError):
            probe.unlink()


# ------------------------------------------------------------------ a full disk

_FULL_ERRNOS = {errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)}
_FULL_TEXTS = ("no space left on device", "disk quota exceeded")


def is_disk_full(exc: BaseException | None) -> bool:
    """Whether `exc`, or an exception it was raised from, is a full disk (ENOSPC) or quota (EDQUOT)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in _FULL_ERRNOS:
            return True
        if isinstance(exc, OSError) and any(t in str(exc).lower() for t in _FULL_TEXTS):
            return True  # pyarrow and zipfile report some write errors with the text only
        exc = exc.__cause__ or exc.__context__
    return False


def disk_full_error(exc: BaseException, path: str | os.PathLike) -> DiskFullError:
    """The `DiskFullError` of `exc` (see `is_disk_full`) while writing `path`."""
    code = exc.errno if isinstance(exc, OSError) and exc.errno in _FULL_ERRNOS else errno.ENOSPC
    return DiskFullError(code, os.strerror(code), os.fspath(path))


class DiskFullError(OSError):
    """Writing `filename` (an output folder) ran out of disk space or quota; nothing was left half-written."""

    def __str__(self) -> str:
        quota = self.errno == getattr(errno, "EDQUOT", None)
        what = "the disk quota is exceeded" if quota else "the disk is full (no space left on device)"
        return (f"{what} while writing {self.filename}: what was being written was not saved and no file "
                "is left half-written; free some space or choose another --out")


# ------------------------------------------------------------------ one writer per folder

LOCK_NAME = ".jaxeac.lock"
_HELD: dict[str, list] = {}  # real path of a folder this process holds -> [lock fd, depth]


@contextlib.contextmanager
def folder_lock(out: str | os.PathLike) -> Iterator[Path]:
    """Hold an advisory lock on output folder `out` (created if needed) for the block.

    A second process locking the same folder gets a `UsageError` at once (no waiting), so
    two runs never write one folder together. Re-entrant within a process (a command that
    holds its folder can write into it). On release the lock file, ``out/.jaxeac.lock``, and
    any staging folder still there (one whose removal raced a writer, say) are removed;
    folders this call created are removed again if they are then empty.
    """
    out = check_out_path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} exists and is not a directory; choose another path")
    created = _make_dirs(out)
    key = os.path.realpath(out)
    if key in _HELD:
        _HELD[key][1] += 1
        try:
            yield out
        finally:
            _HELD[key][1] -= 1
        return
    try:
        fd = _acquire(out / LOCK_NAME, out)
    except BaseException:
        _remove_if_empty(created)
        raise
    _HELD[key] = [fd, 1]
    try:
        yield out
    finally:
        del _HELD[key]
        if not _STAGES.get(key):
            _remove_stale_stages(out)
        with contextlib.suppress(OSError):
            os.unlink(out / LOCK_NAME)  # while still locked: a waiting process sees a new file
        os.close(fd)
        _remove_if_empty(created)


def _make_dirs(out: Path) -> list[Path]:
    """mkdir -p `out`; the folders it created, innermost first."""
    missing = []
    p = out.absolute()
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _remove_if_empty([m for m in missing if m.exists()])
        if is_disk_full(exc):
            raise disk_full_error(exc, out) from exc
        reason = exc.strerror or exc
        raise UsageError(f"cannot write to --out {out}: {reason}; choose a writable folder") from None
    return missing


def _remove_if_empty(folders: list[Path]) -> None:
    for folder in folders:  # innermost first
        try:
            folder.rmdir()
        except OSError:
            return


def _acquire(path: Path, out: Path) -> int:
    """Open and flock `path` (non-blocking); make sure it is still the file at `path`."""
    import fcntl

    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o644)
        except OSError as exc:
            if is_disk_full(exc):
                raise disk_full_error(exc, out) from exc
            reason = exc.strerror or exc
            raise UsageError(f"cannot write to --out {out}: {reason}; choose a writable folder") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode("ascii", "replace").strip()
            os.close(fd)
            who = f" (process {holder})" if holder.isdigit() else ""
            raise UsageError(f"{out} is being written by another jaxeac run{who}; wait for it to finish "
                             "or choose another --out") from None
        except OSError:  # a filesystem without flock (some network mounts): go on unlocked
            return fd
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            with contextlib.suppress(OSError):  # the holder's pid, for the message (a full disk: none)
                os.ftruncate(fd, 0)
                os.write(fd, f"{os.getpid()}\n".encode())
            return fd
        os.close(fd)  # the previous holder removed it as we opened it: take the new one


def read_json_object(path: str | os.PathLike, fix: str = "re-run the command that wrote it") -> dict:
    """A JSON file that must hold an object (summary.json, a sweep manifest); anything else
    (missing, unreadable, not UTF-8, not JSON, a list) is one `UsageError` naming the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UsageError(f"{path} is missing; {fix}") from None
    except UnicodeDecodeError:
        raise UsageError(f"{path} is not UTF-8 text (a damaged or foreign file); {fix}") from None
    except OSError as exc:
        raise UsageError(f"cannot read {path} ({exc.strerror or exc}); {fix}") from None
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise UsageError(f"{path} is not valid JSON ({exc.msg} at line {exc.lineno}); {fix}") from None
    except RecursionError:
        raise UsageError(f"{path} is nested too deeply to be a jaxeac file; {fix}") from None
    if not isinstance(obj, dict):
        raise UsageError(f"{path} holds a JSON {type(obj).__name__}, not an object; {fix}")
    return obj


def json_field(obj: dict, key: str, kind: type | tuple, path, fix: str = "re-run the command that wrote it"):
    """`obj[key]` if it is of `kind` (bools are not ints), else one `UsageError` naming file and field."""
    value = obj.get(key)
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if value is None or isinstance(value, bool) and bool not in kinds or not isinstance(value, kinds):
        expected = " or ".join(k.__name__ for k in kinds)
        raise UsageError(f"{path}: field {key!r} is {value!r}, expected {expected}; {fix}")
    return value
