"""Output locations: claiming them before the work, and writing them without destroying anything.

Every folder the tool writes whole (a run, a comparison, a report's figure
folder) carries a marker file, ``.pipeline-sim.json``, that lists the names
the tool wrote there. The rules (user documentation: docs/formats.md,
"Output locations"):

* A target that does not exist, or an empty folder, is written.
* A folder whose marker says this tool wrote everything in it is replaced
  whole and atomically: the new outputs are written into a hidden staging
  folder beside it and renamed into place at the end, so a failed or
  interrupted run leaves the previous outputs as they were.
* Any other existing folder is refused (:class:`UserError`, exit 2) unless
  ``force``: then the new outputs are renamed into it one by one, the names
  its own earlier marker lists and this run did not write again are
  removed, and every other file is left alone. The working directory and
  its ancestors, which cannot be renamed, are always written this way.
* A target that exists and is not a folder is refused, ``force`` or not.
* The staging folder is created when the location is claimed, before any
  simulation, so an unwritable location fails at once, in one line.
* Staging folders are named ``.NAME.pipeline-sim-PID-XXXX.tmp`` (or
  ``.pipeline-sim-PID-XXXX.tmp`` inside a forced folder). One whose process
  has gone is the leftover of a killed write; the next claim of the same
  target removes it (or, for the previous outputs set aside during a
  replacement, puts them back if the new ones never arrived).

Files are created with the modes of the user's umask, like any other
program's (the temporary names' private modes are not kept).
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import tempfile
from pathlib import Path

from pipeline_sim.errors import UserError

MARKER = ".pipeline-sim.json"
WRITTEN_BY = "pipeline-sim"
PREVIOUS = "previous"   # inside a ``.old`` folder: the outputs set aside while their replacement lands

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


def _cannot_write(option: str, target: Path | str, where: Path, exc: OSError) -> UserError:
    reason = exc.strerror or str(exc)
    return UserError(f"{option} {target}: cannot write to {where}: {reason} (nothing was written)")


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # someone else's live process
        return True
    except OSError:
        return True
    return True


def staging_prefix(name: str | None) -> str:
    """The start of a temporary name for target ``name`` (None: a staging folder inside a forced folder)."""
    return (f".{name}." if name else ".") + f"{WRITTEN_BY}-{os.getpid()}-"


ANY_NAME = "*"


def _leftover_pattern(name: str | None) -> re.Pattern[str]:
    head = {None: r"\.", ANY_NAME: r"\..+\."}.get(name, rf"\.{re.escape(name or '')}\.")
    return re.compile(head + rf"{WRITTEN_BY}-(\d+)-[A-Za-z0-9_]+\.(tmp|old)$")


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink()


def clean_leftovers(folder: Path, name: str | None) -> list[Path]:
    """Remove, in ``folder``, the temporary files and folders of dead processes for target ``name``.

    ``name`` None: the staging folders of a forced write into ``folder``
    itself; :data:`ANY_NAME`: those of every target in ``folder``. Returns
    what was removed. A ``.old`` folder (previous outputs set aside during a replacement) goes
    back into place when its target is missing, and is removed otherwise.
    """
    pattern = _leftover_pattern(name)
    removed = []
    try:
        entries = list(folder.iterdir())
    except OSError:
        return removed
    for entry in entries:
        m = pattern.match(entry.name)
        if m is None or _pid_alive(int(m.group(1))):
            continue
        target = folder / name if name not in (None, ANY_NAME) else None
        previous = entry / PREVIOUS
        try:
            if m.group(2) == "old" and target is not None and not os.path.lexists(target) and previous.exists():
                os.replace(previous, target)
            _remove(entry)
        except OSError:
            continue
        removed.append(entry)
    return removed


def read_marker(folder: Path) -> dict | None:
    """The marker of a folder this tool wrote, or None."""
    try:
        doc = json.loads((folder / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if not isinstance(doc, dict) or doc.get("written_by") != WRITTEN_BY or not isinstance(doc.get("files"), list):
        return None
    return doc


def _unmarked_run_names(folder: Path) -> frozenset[str] | None:
    """A run folder written before markers existed: its run.json has the run's keys."""
    try:
        info = json.loads((folder / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if isinstance(info, dict) and all(k in info for k in _UNMARKED_RUN_KEYS):
        return _UNMARKED_RUN_NAMES
    return None


def _own_names(folder: Path) -> frozenset[str] | None:
    """The names this tool wrote in ``folder``, or None if nothing says it wrote any."""
    marker = read_marker(folder)
    if marker is not None:
        return frozenset(str(n) for n in marker["files"])
    return _unmarked_run_names(folder)


def _foreign_entries(folder: Path, own: frozenset[str]) -> list[str]:
    ours = (_leftover_pattern(None), _leftover_pattern(ANY_NAME))
    return sorted(e.name for e in folder.iterdir()
                  if e.name != MARKER and e.name not in own and not any(p.match(e.name) for p in ours))


def _contains_cwd(path: Path) -> bool:
    try:
        cwd = Path.cwd().resolve()
    except OSError:
        return False
    return cwd == path or path in cwd.parents


class OutputFolder:
    """A claimed output folder: write into :attr:`staging`, then :meth:`commit` (or :meth:`abort`).

    Use as a context manager around the whole job: the location is checked
    and the staging folder created on entry (before any work), the outputs
    land on :meth:`commit`, and an exception anywhere removes the staging
    folder and leaves the target untouched.
    """

    def __init__(self, target: str | Path, kind: str, *, force: bool = False, option: str = "--out") -> None:
        self.kind = kind
        self.target = Path(os.path.abspath(target))
        self.merge = False
        self._previous_own: frozenset[str] = frozenset()
        where = f"{option} {target}"
        if os.path.lexists(self.target) and not self.target.is_dir():
            raise UserError(f"{where}: exists and is not a folder; give a new or empty folder (nothing was written)")
        parent = self.target.parent
        if self.target.is_dir():
            clean_leftovers(parent, self.target.name)
            clean_leftovers(self.target, None)
            own = _own_names(self.target)
            foreign = _foreign_entries(self.target, own or frozenset())
            if foreign and not force:
                what = ("holds files pipeline-sim did not write" if own is not None
                        else "exists and was not written by pipeline-sim")
                shown = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
                raise UserError(f"{where}: {what} ({shown}); give a new or empty folder, or add --force to write "
                                "into it without removing those")
            self._previous_own = own or frozenset()
            # a forced folder keeps its other files; the working directory and a link cannot be swapped whole
            self.merge = bool(foreign) or _contains_cwd(self.target) or self.target.is_symlink()
        else:
            try:
                parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise _cannot_write(option, target, parent, exc) from None
            clean_leftovers(parent, self.target.name)
        home = self.target if self.merge else parent
        try:
            self.staging = Path(tempfile.mkdtemp(prefix=staging_prefix(None if self.merge else self.target.name),
                                                 suffix=".tmp", dir=home))
            os.chmod(self.staging, ordinary_mode(directory=True))
        except OSError as exc:
            raise _cannot_write(option, target, home, exc) from None
        self._done = False

    def __enter__(self) -> OutputFolder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.abort()

    def abort(self) -> None:
        """Drop the staging folder; the target stays as it was."""
        if not self._done:
            shutil.rmtree(self.staging, ignore_errors=True)
            self._done = True

    def _write_marker(self, folder: Path, names: list[str]) -> None:
        doc = {"written_by": WRITTEN_BY, "kind": self.kind, "files": sorted(names)}
        path = folder / MARKER
        path.write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n", encoding="utf-8")

    def commit(self) -> Path:
        """Move the staged outputs into place; return the target."""
        names = sorted(e.name for e in self.staging.iterdir() if e.name != MARKER)
        if self.merge:
            self._commit_merge(names)
        else:
            self._commit_replace(names)
        self._done = True
        return self.target

    def _commit_replace(self, names: list[str]) -> None:
        self._write_marker(self.staging, names)
        parent = self.target.parent
        old = None
        if self.target.exists():
            old = Path(tempfile.mkdtemp(prefix=staging_prefix(self.target.name), suffix=".old", dir=parent))
            os.replace(self.target, old / PREVIOUS)
        os.replace(self.staging, self.target)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)

    def _commit_merge(self, names: list[str]) -> None:
        trash = self.staging / ".replaced"
        trash.mkdir()
        for name in names:
            dest = self.target / name
            if os.path.lexists(dest) and (dest.is_dir() or (self.staging / name).is_dir()):
                os.replace(dest, trash / name)
            os.replace(self.staging / name, dest)
        for name in self._previous_own - set(names):
            stale = self.target / name
            if os.path.lexists(stale):
                _remove(stale)
        marker_tmp = self.staging / MARKER
        self._write_marker(self.staging, names)
        os.replace(marker_tmp, self.target / MARKER)
        shutil.rmtree(self.staging, ignore_errors=True)


def owned_file(path: Path, signature: str) -> bool:
    """Whether the file at ``path`` starts (in its first 4 KiB) with what this tool writes there."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096).decode("utf-8", errors="replace")
    except OSError:
        return False
    return signature in head


def check_output_file(path: Path, signatures: tuple[str, ...], *, force: bool, option: str) -> None:
    """Refuse (one line) an existing file this tool did not write, unless ``force``; check the folder is writable."""
    if os.path.lexists(path):
        if path.is_dir():
            raise UserError(f"{option} {path}: is a folder; give a file name")
        if not force and not any(owned_file(path, s) for s in signatures):
            raise UserError(f"{option} {path}: exists and was not written by pipeline-sim; give a new file name, "
                            "or add --force to replace it")
    check_writable_folder(path.parent, option)


def check_writable_folder(folder: Path, option: str) -> None:
    """Create ``folder`` if needed and prove a file can be created in it; else a one-line :class:`UserError`."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=staging_prefix("probe"), suffix=".tmp", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        if exc.errno in (errno.ENOTDIR, errno.EEXIST) and folder.exists() and not folder.is_dir():
            raise UserError(f"{option} {folder}: exists and is not a folder") from None
        raise _cannot_write(option, folder, folder, exc) from None


__all__ = ["ANY_NAME", "MARKER", "OutputFolder", "check_output_file", "check_writable_folder", "clean_leftovers",
           "ordinary_mode", "owned_file", "read_marker", "staging_prefix", "umask"]
