"""The project's error type for bad input.

:class:`InputError` is a ``ValueError`` (existing ``except ValueError`` handling keeps working) whose message
is one line that names the file or option and the problem, e.g.
``cam.json: unknown field 'min_Depth'; known fields: [...]``. The command line prints it to stderr and
exits with code 2 (see ``docs/conventions.md``, "Errors").
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

__all__ = ["InputError", "check_known_keys", "one_line"]


def one_line(text: object) -> str:
    """``text`` as a single line (newlines and runs of blanks collapsed)."""
    return " ".join(str(text).split())


class InputError(ValueError):
    """Bad input (a file, its contents or an option); the message names where and what, on one line."""

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        msg = one_line(message)
        if path is not None and not msg.startswith(str(path)):
            msg = f"{path}: {msg}"
        super().__init__(msg)
        self.path = None if path is None else str(path)


def check_known_keys(data: dict, known: Iterable[str], where: str) -> None:
    """Raise :class:`InputError` if ``data`` has a key outside ``known``, naming it and listing the known ones."""
    known = list(known)
    unknown = [k for k in data if k not in known]
    if unknown:
        raise InputError(f"{where}: unknown field {unknown[0]!r}; known fields: {sorted(known)}")
