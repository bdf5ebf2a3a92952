"""Checks the commands run before any compute: sizes that cannot fit or finish, paths to write.

Each refusal is one line naming the numbers and the fix (`jaxeac.errors.UsageError`).
"""

from __future__ import annotations

import argparse
import os
import stat

from jaxeac.cli.flags import show
from jaxeac.errors import UsageError


def fit_grid(args: argparse.Namespace, settings, env):
    """Refuse sizes that cannot fit in memory or finish (`check_grid_resources`), with the numbers;
    an automatic chunk size that would not fit becomes the largest that does."""
    import dataclasses

    from jaxeac.experiments.common import check_grid_resources
    from jaxeac.experiments.grid import process_share

    first, n = process_share(settings.seeds, args.process_id, args.num_processes)
    chunk = check_grid_resources(settings, env, n_seeds=n, first_seed=first)
    return settings if chunk == settings.chunk_size else dataclasses.replace(settings, chunk_size=chunk)


def fit_sweep(sweep):
    """`check_grid_resources` at every point of a sweep (each distinct size once); an automatic
    chunk size too large for some point becomes the largest that fits them all."""
    import dataclasses

    from jaxeac.experiments.common import check_grid_resources

    seen, chunks = set(), []
    for point in sweep.points():
        settings = sweep.settings(point)
        size = (settings.preset, settings.map_file, settings.env, settings.slip, settings.trials,
                settings.chances)
        if size in seen:
            continue
        seen.add(size)
        chunks.append(check_grid_resources(settings, settings.make_env()))
    if sweep.base.chunk_size is None and any(c is not None for c in chunks):
        sweep = dataclasses.replace(sweep, base=dataclasses.replace(
            sweep.base, chunk_size=min(c for c in chunks if c is not None)))
    return sweep


def check_compare_size(run_dir, resamples: int) -> None:
    """Refuse --resamples whose statistics cannot fit in memory (trials from the run's summary.json)."""
    import json
    from pathlib import Path

    from jaxeac.experiments.common import check_compare_resources

    try:
        trials = json.loads((Path(run_dir) / "summary.json").read_text())["trials"]
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        trials = None
    if not isinstance(trials, int) or isinstance(trials, bool) or trials < 1:
        trials = 1  # compare_run_dir names what is wrong with the folder
    check_compare_resources(resamples, trials)


def render_targets(path, n_throws: int) -> list:
    """The files `throw_command` draws for `n_throws` throws into `path` (`<stem>_<i>.png` for several)."""
    from pathlib import Path

    path = Path(path)
    if n_throws == 1:
        return [path]
    return [path.with_name(f"{path.stem}_{i}{path.suffix}") for i in range(n_throws)]


def _check_writable_file(text: str, path) -> None:
    """Refuse an existing `path` that is not a regular file (a device such as /dev/full, a pipe)
    or that cannot be written."""
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return
    except OSError as exc:  # a name too long, a loop of links
        raise UsageError(f"--render {text}: {exc.strerror or exc}; pick another path") from None
    if stat.S_ISDIR(mode):
        raise UsageError(f"--render would write {path}, which is a folder; pick another file name")
    if not stat.S_ISREG(mode):
        raise UsageError(f"--render {text}: {path} is not a regular file (a device, pipe or socket); name a "
                         ".png file in a folder, e.g. --render deck.png")
    if not os.access(path, os.W_OK):
        raise UsageError(f"--render {text}: cannot write to {path}; pick a writable file")


def render_path(text: str, n_throws: int) -> str:
    """The PNG file `throw --render` writes (``.png`` added to a name without a suffix, so the
    path reported is the one written); refuses empty names, folders, devices and other files
    that are not regular, files that cannot be written, other suffixes and folders that do not
    exist (nothing is created)."""
    from pathlib import Path

    if not text.strip() or "\0" in text:
        raise UsageError(f"--render {show(text)} is not a file name; name a .png file, e.g. "
                         "--render deck.png")
    path = Path(text)
    for probe in (path, path.parent):
        try:
            os.stat(probe)
        except (FileNotFoundError, NotADirectoryError):
            pass
        except OSError as exc:  # a name too long, a loop of links
            raise UsageError(f"--render {text}: {exc.strerror or exc}; pick another path") from None
    if path.is_dir() or text.endswith(("/", os.sep)):
        raise UsageError(f"--render {text} is a folder; name a file in it, e.g. --render "
                         f"{(path / 'deck.png').as_posix()}")
    _check_writable_file(text, path)  # `/dev/full` is no picture, even with `.png` added
    if path.suffix == "":
        path = path.with_name(path.name + ".png")
    elif path.suffix.lower() != ".png":
        raise UsageError(f"--render {text}: pictures are PNG files; name a .png file, e.g. "
                         f"{path.with_suffix('.png')}")
    folder = path.parent
    if not folder.is_dir():
        problem = "is not a folder" if folder.exists() else "does not exist"
        raise UsageError(f"--render {text}: folder {folder} {problem}; create it first or pick "
                         "another path")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"--render {text}: cannot write to folder {folder}; pick a writable folder")
    for target in render_targets(path, n_throws):
        _check_writable_file(text, target)
    return str(path)
