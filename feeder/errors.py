"""Errors that reach the user as one line (CLI exit code 2)."""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input: names the field (or file) and says what is wrong.

    ``str(err)`` is the one line the CLI prints, e.g. ``--part: expected LxWxT in µm``.
    """

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message
