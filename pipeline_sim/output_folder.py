"""Output locations: claiming them before the work, and writing them without destroying anything.

Every folder the tool writes whole (a run, a comparison, a report's figure
folder, a sweep point) carries a marker file, ``.pipeline-sim.json``, that
lists every file the tool wrote there (relative path, size, modification
time) and every folder. A file whose size or time no longer matches, or
that the marker does not list, at any depth, is the user's. The rules (user
documentation: docs/outputs.md, "Output locations"):

* A target that does not exist, or an empty folder, is written.
* A folder holding only what its marker lists, unchanged, and written for
  the same kind of output, is replaced whole and atomically: the new outputs
  are written into a hidden staging folder beside it and swapped in at the
  end, so a failed or interrupted run leaves the previous outputs as they
  were.
* Any other existing folder is refused (:class:`UserError`, exit 2) unless
  ``force``: then the new files are renamed into it one by one (each
  replacing a file of the same path), the tool's own earlier files that
  were not written again are removed if unchanged, and everything else is
  left alone. Folders that cannot be swapped (the working directory or one
  of its parents, a link, a mount point, another file system than their
  parent's) are always written this way.
* A target that exists and is not a folder is refused, ``force`` or not.
* The staging folder is created when the location is claimed, before any
  simulation, so an unwritable location fails at once, in one line. The
  folder is checked again just before the outputs land: a file the user
  added meanwhile is kept (the outputs are then written in beside it).
* Staging folders and temporary files are named
  ``.NAME.pipeline-sim-PID-XXXX.tmp`` (``.old`` for previous outputs set
  aside during a swap) and stay locked (``flock``) while their writer
  lives. An unlocked one is the leftover of a killed write; the next claim
  of the same folder removes it, or, for previous outputs set aside when
  the new ones never arrived, puts them back.

Files and folders are created with the modes of the user's umask, like any
other program's (a replaced folder keeps its own mode, and a set-group-id
parent's group is inherited).
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import re
import shutil
import stat
import tempfile
import time
from pathlib import Path

from pipeline_sim.errors import OutputError, UserError

MARKER = ".pipeline-sim.json"
WRITTEN_BY = "pipeline-sim"
PREVIOUS = "previous"   # inside a ``.old`` folder: the outputs set aside while their replacement lands
# an unlocked leftover of a process that may still be alive is removed only when at least this old
# (a writer locks its staging folder microseconds after creating it)
_YOUNG_LEFTOVER_S = 60.0
_LEFTOVER = re.compile(r"^\.(?:(?P<name>.+)\.)?" + WRITTEN_BY + r"-(?P<pid>\d+)-[A-Za-z0-9_]+\.(?P<kind>tmp|old)$")

# The names a run folder held before folders carried a marker: such a folder is recognised as the tool's own.
_UNMARKED_RUN_NAMES = frozenset({"image.npy", "image.exr", "image.png", "counters.csv", "timing.csv", "queues.csv",
                                 "run.json", "report.md", "report.html", "report_files"})
_UNMARKED_RUN_KEYS = ("scene_digest", "arch", "frame_cycles")


def umask() -> int:
    """The process's umask (read from /proc where it can be, so no other thread sees it change)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def ordinary_mode(directory: bool) -> int:
    """The mode ``open()`` or ``mkdir()`` would give a new file or folder under the current umask."""
    return (0o777 if directory else 0o666) & ~umask()


def staging_prefix(name: str | None) -> str:
    """The start of a temporary name for target ``name`` (None: a staging folder inside a forced folder)."""
    return (f".{name}." if name else ".") + f"{WRITTEN_BY}-{os.getpid()}-"


def is_leftover_name(name: str) -> bool:
    """Whether ``name`` is a temporary name of this tool's (a staging folder or file)."""
    return _LEFTOVER.match(name) is not None


def hold_lock(fd: int) -> None:
    """Lock an open temporary file or folder for as long as ``fd`` is open (see :func:`clean_leftovers`)."""
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:   # someone else's live process
        return True
    return True


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink()


def clean_leftovers(folder: Path) -> list[Path]:
    """Remove the temporary files and folders that killed writers left in ``folder``; return them.

    A leftover is one no live writer holds locked, and whose process is
    gone, is this process (a previous life of it, as in a container where
    the tool is always process 1) or created it long ago. A ``.old`` folder
    (previous outputs set aside during a replacement) goes back into place
    when its target is missing, and is removed otherwise.
    """
    removed = []
    try:
        entries = list(folder.iterdir())
    except OSError:
        return removed
    for entry in entries:
        m = _LEFTOVER.match(entry.name)
        if m is None or entry.is_symlink():
            continue
        pid = int(m.group("pid"))
        try:
            st = entry.lstat()
            fd = os.open(entry, os.O_RDONLY)
        except OSError:
            continue
        try:
            try:
                hold_lock(fd)
            except OSError:
                continue   # a live writer holds it
            if pid != os.getpid() and _pid_alive(pid) and time.time() - st.st_mtime < _YOUNG_LEFTOVER_S:
                continue   # perhaps a writer between creating and locking it
            name, previous = m.group("name"), entry / PREVIOUS
            if m.group("kind") == "old" and name and not os.path.lexists(folder / name) and previous.exists():
                os.replace(previous, folder / name)
            _remove(entry)
            removed.append(entry)
        except OSError:
            continue
        finally:
            os.close(fd)
    return removed


# ---------------------------------------------------------------------------
# What a folder holds, and whose it is


def _stamp(st: os.stat_result) -> list[int]:
    return [st.st_size, st.st_mtime_ns]


def _inventory(folder: Path) -> tuple[dict[str, list[int]], list[str]]:
    """Every file (relative path -> size and time) and folder under ``folder``, this tool's temporary
    names and the top-level marker left out; links count as files."""
    files, folders = {}, []
    for root, dirs, names in os.walk(folder):
        rel_root = os.path.relpath(root, folder)
        for d in list(dirs):
            rel = os.path.normpath(os.path.join(rel_root, d))
            if is_leftover_name(d):
                dirs.remove(d)
            elif os.path.islink(os.path.join(root, d)):
                dirs.remove(d)
                files[rel] = _stamp(os.lstat(os.path.join(root, d)))
            else:
                folders.append(rel)
        for n in names:
            rel = os.path.normpath(os.path.join(rel_root, n))
            if rel != MARKER and not is_leftover_name(n):
                files[rel] = _stamp(os.lstat(os.path.join(root, n)))
    return files, sorted(folders)


def _plain_relative(path: object) -> bool:
    """A marker entry may only name something inside its folder."""
    return (isinstance(path, str) and path not in ("", ".") and not os.path.isabs(path)
            and os.path.normpath(path) == path and ".." not in Path(path).parts and path != MARKER)


def read_marker(folder: Path) -> dict | None:
    """The marker of a folder this tool wrote, or None (a marker naming anything outside its folder is
    not this tool's)."""
    try:
        doc = json.loads((folder / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if not isinstance(doc, dict) or doc.get("written_by") != WRITTEN_BY:
        return None
    files, folders = doc.get("files"), doc.get("folders")
    if not isinstance(files, dict) or not isinstance(folders, list):
        return None
    if not all(_plain_relative(p) for p in [*files, *folders]):
        return None
    if not all(isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) for x in v) for v in files.values()):
        return None
    return doc


def _unmarked_run_marker(folder: Path) -> dict | None:
    """A run folder written before markers existed: its run.json has the run's keys; what it holds
    under the run's names counts as the tool's."""
    try:
        info = json.loads((folder / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if not isinstance(info, dict) or not all(k in info for k in _UNMARKED_RUN_KEYS):
        return None
    files, folders = _inventory(folder)
    own = lambda rel: Path(rel).parts[0] in _UNMARKED_RUN_NAMES and (  # noqa: E731
        Path(rel).parts[0] != "report_files" or rel == "report_files" or rel.endswith(".png"))
    return {"written_by": WRITTEN_BY, "kind": "run", "files": {r: s for r, s in files.items() if own(r)},
            "folders": [r for r in folders if own(r)]}


def _foreign_entries(folder: Path, marker: dict | None) -> list[str]:
    """What in ``folder`` the marker does not vouch for: unlisted, or changed since the tool wrote it."""
    listed = marker["files"] if marker else {}
    known_folders = set(marker["folders"]) if marker else set()
    files, folders = _inventory(folder)
    foreign = [rel for rel, st in files.items() if listed.get(rel) != st]
    foreign += [rel for rel in folders if rel not in known_folders]
    return sorted(foreign)


def _contains_cwd(path: Path) -> bool:
    try:
        cwd = Path.cwd().resolve()
    except OSError:
        return False
    real = path.resolve()
    return cwd == real or real in cwd.parents


def _cannot_swap(target: Path) -> bool:
    """Whether ``target`` cannot be replaced by a rename: the working directory or a parent of it, a
    link, a mount point, or a folder on another file system than its parent."""
    if target.is_symlink() or _contains_cwd(target) or os.path.ismount(target):
        return True
    return os.stat(target).st_dev != os.stat(target.parent).st_dev


def _shown(names: list[str]) -> str:
    return ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")


def _cannot_write(option: str, target: Path | str, where: Path, exc: OSError) -> UserError:
    reason = exc.strerror or str(exc)
    return UserError(f"{option} {target}: cannot write to {where}: {reason} (nothing was written)")


class OutputFolder:
    """A claimed output folder: write into :attr:`staging`, then :meth:`commit` (or :meth:`abort`).

    Use as a context manager around the whole job: the location is checked
    and the staging folder created on entry (before any work), the outputs
    land on :meth:`commit`, and an exception anywhere removes the staging
    folder and leaves the target untouched.
    """

    def __init__(self, target: str | Path, kind: str, *, force: bool = False, option: str = "--out") -> None:
        self.kind = kind
        self.given = str(target)
        self.option = option
        self.target = Path(os.path.abspath(target))
        self.force = force
        where = f"{option} {target}"
        if os.path.lexists(self.target) and not self.target.is_dir():
            raise UserError(f"{where}: exists and is not a folder; give a new or empty folder (nothing was written)")
        parent = self.target.parent
        self._previous: dict | None = None
        self.merge = False
        mode = ordinary_mode(directory=True)
        if self.target.is_dir():
            try:
                clean_leftovers(parent)
                clean_leftovers(self.target)
                self._previous = read_marker(self.target) or _unmarked_run_marker(self.target)
                foreign = _foreign_entries(self.target, self._previous)
                mode = stat.S_IMODE(os.stat(self.target).st_mode)
                unswappable = _cannot_swap(self.target) or not os.access(self.target, os.W_OK)
            except OSError as exc:
                raise _cannot_write(option, target, self.target, exc) from None
            if not force:
                if foreign:
                    what = ("holds files pipeline-sim did not write, or that changed since"
                            if self._previous is not None else "exists and was not written by pipeline-sim")
                    raise UserError(f"{where}: {what} ({_shown(foreign)}); give a new or empty folder, or add "
                                    "--force to write into it and keep those")
                if self._previous is not None and self._previous.get("kind") != kind:
                    raise UserError(f"{where}: holds the outputs of a {self._previous.get('kind')}, not of a "
                                    f"{kind}; give another folder, or add --force to write into it")
            self.merge = bool(foreign) or unswappable
        else:
            try:
                parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise _cannot_write(option, target, parent, exc) from None
            clean_leftovers(parent)
        home = self.target if self.merge else parent
        try:
            self.staging = Path(tempfile.mkdtemp(prefix=staging_prefix(None if self.merge else self.target.name),
                                                 suffix=".tmp", dir=home))
            self._lock = os.open(self.staging, os.O_RDONLY)
            hold_lock(self._lock)
            inherited = os.stat(self.staging).st_mode & stat.S_ISGID
            os.chmod(self.staging, mode | inherited)
        except OSError as exc:
            raise _cannot_write(option, target, home, exc) from None
        self._done = False

    def __enter__(self) -> OutputFolder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            return
        self.abort()
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            raise self._failed(exc) from exc

    def _failed(self, exc: OSError) -> OutputError:
        reason = exc.strerror
        if reason is None:   # some writers report a short write without an errno
            try:
                full = shutil.disk_usage(self.target.parent).free < (1 << 20)
            except OSError:
                full = False
            reason = os.strerror(errno.ENOSPC) if full else str(exc)
        where = f" ({exc.filename})" if exc.filename else ""
        return OutputError(f"{self.option} {self.given}: writing the outputs failed{where}: {reason}; "
                           "the previous contents are as they were")

    def abort(self) -> None:
        """Drop the staging folder; the target stays as it was."""
        if not self._done:
            shutil.rmtree(self.staging, ignore_errors=True)
            os.close(self._lock)
            self._done = True

    def _marker(self, folder: Path) -> str:
        files, folders = _inventory(folder)
        doc = {"written_by": WRITTEN_BY, "kind": self.kind, "files": files, "folders": folders}
        return json.dumps(doc, indent=1, sort_keys=True, allow_nan=False) + "\n"

    def commit(self) -> Path:
        """Move the staged outputs into place; return the target."""
        try:
            (self.staging / MARKER).write_text(self._marker(self.staging), encoding="utf-8")
            os.chmod(self.staging / MARKER, ordinary_mode(directory=False))
            if self.merge or not self._swap():
                self._commit_merge()
        except OSError as exc:
            self.abort()
            raise self._failed(exc) from exc
        shutil.rmtree(self.staging, ignore_errors=True)
        os.close(self._lock)
        self._done = True
        return self.target

    def _swap(self) -> bool:
        """Replace the target whole; False if it must be merged instead (it changed since the claim, or
        cannot be moved)."""
        if not os.path.lexists(self.target):
            try:
                os.rename(self.staging, self.target)   # fails if a folder appeared meanwhile and is not empty
                return True
            except OSError:
                pass
        if not self.target.is_dir() or self.target.is_symlink():
            raise OSError(errno.EEXIST, "appeared as a file while the outputs were being made", str(self.target))
        current = read_marker(self.target) or _unmarked_run_marker(self.target)
        if _foreign_entries(self.target, current):
            self._previous = current
            return False          # the user put something there meanwhile: keep it
        old = Path(tempfile.mkdtemp(prefix=staging_prefix(self.target.name), suffix=".old", dir=self.target.parent))
        old_lock = os.open(old, os.O_RDONLY)
        try:
            hold_lock(old_lock)
            try:
                os.replace(self.target, old / PREVIOUS)
            except OSError as exc:
                if exc.errno in (errno.EBUSY, errno.EXDEV, errno.EPERM, errno.EACCES):
                    os.rmdir(old)
                    return False
                raise
            os.replace(self.staging, self.target)
            shutil.rmtree(old, ignore_errors=True)
        finally:
            os.close(old_lock)
        return True

    def _commit_merge(self) -> None:
        new_files, new_folders = _inventory(self.staging)
        for rel in new_folders:
            dest = self.target / rel
            if os.path.lexists(dest) and (dest.is_symlink() or not dest.is_dir()):
                raise OSError(errno.EEXIST, "a file of the user's is where an output folder goes", str(dest))
        for rel in new_files:
            dest = self.target / rel
            if dest.is_dir() and not dest.is_symlink():
                raise OSError(errno.EISDIR, "a folder of the user's is where an output file goes", str(dest))
        for rel in new_folders:
            (self.target / rel).mkdir(exist_ok=True)
        for rel in new_files:
            os.replace(self.staging / rel, self.target / rel)
        previous = self._previous or {"files": {}, "folders": []}
        for rel, st in previous["files"].items():
            stale = self.target / rel
            if rel not in new_files and os.path.lexists(stale) and _stamp(stale.lstat()) == st:
                stale.unlink()    # the tool's own earlier output, unchanged and not written again
        for rel in sorted(previous["folders"], key=lambda r: -len(Path(r).parts)):
            if rel not in new_folders:
                try:
                    (self.target / rel).rmdir()   # only when empty
                except OSError:
                    pass
        os.replace(self.staging / MARKER, self.target / MARKER)


# ---------------------------------------------------------------------------
# Single output files


def owned_file(path: Path, patterns: tuple[re.Pattern[str], ...]) -> bool:
    """Whether the file at ``path`` begins (in its first 4 KiB) as this tool writes it."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096).decode("utf-8", errors="replace")
    except OSError:
        return False
    return any(p.match(head) for p in patterns)


def check_output_file(path: Path, patterns: tuple[re.Pattern[str], ...], *, force: bool, option: str) -> None:
    """Refuse (one line) an existing file this tool did not write, unless ``force``; check the folder is
    writable and clean its leftovers."""
    if os.path.lexists(path):
        if path.is_dir():
            raise UserError(f"{option} {path}: is a folder; give a file name")
        if not force and not owned_file(path, patterns):
            raise UserError(f"{option} {path}: exists and was not written by pipeline-sim; give a new file name, "
                            "or add --force to replace it")
    check_writable_folder(path.parent, option)


def check_writable_folder(folder: Path, option: str) -> None:
    """Create ``folder`` if needed, clean its leftovers and prove a file can be created in it; else a
    one-line :class:`UserError`."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        clean_leftovers(folder)
        fd, probe = tempfile.mkstemp(prefix=staging_prefix("probe"), suffix=".tmp", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        if folder.exists() and not folder.is_dir():
            raise UserError(f"{option} {folder}: exists and is not a folder") from None
        raise _cannot_write(option, folder, folder, exc) from None


__all__ = ["MARKER", "OutputFolder", "check_output_file", "check_writable_folder", "clean_leftovers", "hold_lock",
           "is_leftover_name", "ordinary_mode", "owned_file", "read_marker", "staging_prefix", "umask"]
