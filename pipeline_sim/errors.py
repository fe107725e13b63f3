"""User-facing errors: one line naming the problem and where it is."""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from pathlib import Path


class UserError(Exception):
    """A problem with the user's input (scene, architecture, sweep, CLI).

    The CLI prints ``str(error)`` on one line and exits with status 2; no
    traceback is shown. The message names the file and key where known.
    """


class OutputError(Exception):
    """Writing the outputs failed for a reason of the machine, not of the input (a full disk, a folder
    made read-only during the run). The CLI prints it on one line and exits with status 1."""


def printable(text: str) -> str:
    """Escape control characters so a message stays on one line."""
    return text if text.isprintable() else text.encode("unicode_escape").decode("ascii")


def did_you_mean(name: str, choices: Iterable[str]) -> str:
    """Return ``" (did you mean 'x'?)"`` for the closest choice, or ``""``."""
    close = difflib.get_close_matches(name, list(choices), n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def unknown_key_error(where: str, key: str, choices: Iterable[str]) -> UserError:
    """Build the error for an unknown setting, suggesting the nearest name."""
    choices = sorted(choices)
    return UserError(
        f"{where}: unknown key '{key}'{did_you_mean(key, choices)}; "
        f"known keys: {', '.join(choices)}"
    )


def read_input_text(path: Path, where: str, what: str) -> tuple[bytes, str]:
    """The bytes and UTF-8 text of the input file ``path`` (a ``what`` file: scene, sweep,
    architecture), or a one-line :class:`UserError` naming ``where``: not found, a folder, not a
    regular file (a FIFO or device would block or never end), unreadable, or not UTF-8."""
    try:
        if path.exists() and not path.is_dir() and not path.is_file():
            raise UserError(f"{where}: not a regular file, expected a TOML {what} file")
        data = path.read_bytes()
    except FileNotFoundError:
        raise UserError(f"{where}: {what} file not found (resolved to '{path.resolve()}')") from None
    except IsADirectoryError:
        raise UserError(f"{where}: is a folder, expected a TOML {what} file") from None
    except OSError as exc:
        raise UserError(f"{where}: cannot read the {what} file: {exc.strerror or exc}") from None
    try:
        return data, data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UserError(f"{where}: not a TOML file: not UTF-8 text at byte {exc.start}") from None
