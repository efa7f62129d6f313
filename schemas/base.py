"""Shared base of every contract: the schema version, the model config and the one error type."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, ValidationError

#: Version of every contract in this package. Bumped whenever a model or a
#: table declaration changes in a way a reader must know about.
SCHEMA_VERSION = "1.1"
#: The largest seed: every seed is a non-negative integer that numpy's and torch's generators take.
MAX_SEED = 2**63 - 1

#: A name that becomes one path component (a city, a run, a simulated city): ASCII letters, digits, ``_ . -``,
#: starting with a letter or digit, at most 64 characters. No separator, no ``..``, nothing a shell expands.
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"


class Contract(BaseModel):
    """Base of all uavplace models: unknown fields are errors, instances are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class InputError(Exception):
    """Bad input: names the file, the line (1-based, when known) and the field.

    ``str(err)`` is one line, ``<file>:<line>: <field>: <message>`` (the parts
    that are known), fit for a terminal and for grep.
    """

    def __init__(
        self,
        path: str | Path | None,
        message: str,
        *,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        self.path = str(path) if path is not None else None
        self.line = line
        self.field = field
        self.message = message
        super().__init__(self.__str__())

    def __reduce__(self):  # noqa: ANN204 - pickled by Ray and multiprocessing: rebuilt with its path, line and field
        return (_input_error, (self.path, self.message, self.line, self.field))

    def __str__(self) -> str:
        parts = []
        if self.path is not None:
            parts.append(self.path if self.line is None else f"{self.path}:{self.line}")
        if self.field:
            parts.append(self.field)
        return ": ".join([*parts, self.message])


def _input_error(path: str | None, message: str, line: int | None, field: str | None) -> InputError:
    return InputError(path, message, line=line, field=field)


def validation_message(exc: ValidationError, default_field: str = "value") -> tuple[str, str]:
    """(field, message) of a pydantic error's first problem, fit for an ``InputError`` (no URL, no input dump).

    ``default_field`` names a problem that belongs to no one field (a cross-field check).
    """
    err = exc.errors()[0]
    message = str(err["msg"]).removeprefix("Value error, ")
    if err["type"] == "json_invalid":
        return "json", message
    return ".".join(map(str, err["loc"])) or default_field, message


def uavplace_version() -> str:
    """The installed distribution's version (``0+src`` when run from a source tree that is not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("uavplace")
    except PackageNotFoundError:
        return "0+src"


def repeated(items: list) -> list:
    """The items listed more than once, sorted: in time linear in the list (a count per item would be quadratic:
    a roles file of a million names never finished)."""
    from collections import Counter

    return sorted(item for item, n in Counter(items).items() if n > 1)
