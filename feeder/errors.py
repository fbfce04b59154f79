"""The one root of every error the package raises on purpose: :class:`FeederError`.

Catch ``FeederError`` to handle anything this package reports; the subclasses
say what kind of trouble it is.  Drivers add theirs (``AmplifierError``,
``SensorLost``) under the same root.
"""

from __future__ import annotations


class FeederError(Exception):
    """Base of every error this package raises on purpose."""


class InputError(FeederError, ValueError):
    """Bad user input: names the field (or file) and says what is wrong.

    ``str(err)`` is the one line the CLI prints, e.g. ``--part: expected LxWxT in µm``.
    """

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message
