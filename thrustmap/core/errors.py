"""User-facing errors: every one names where the problem is and what was expected.

The CLI turns any ``ThrustmapError`` into one line on stderr and exit code 2; anything else is
a bug and is reported as such (with a traceback only under ``--debug``).
"""

from __future__ import annotations


class ThrustmapError(Exception):
    """An error a user can act on: which file, which line or column, what was expected."""

    def __init__(
        self,
        message: str,
        *,
        file: str | None = None,
        line: int | None = None,
        column: str | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.file = file
        self.line = line
        self.column = column

    def __str__(self) -> str:
        where = ""
        if self.file is not None:
            where = str(self.file)
            if self.line is not None:
                where += f":{self.line}"
            where += ": "
        elif self.line is not None:
            where = f"line {self.line}: "
        if self.column is not None:
            where += f"column '{self.column}': "
        return where + self.message


class DataFormatError(ThrustmapError):
    """A data file (stand log, flight log, map file) is not what was expected."""


class FitError(ThrustmapError):
    """The data cannot support the requested fit (too few points, one voltage level, ...)."""


class ConfigError(ThrustmapError):
    """A bad option, range or request (LO >= HI, unknown model or target, ...)."""


class SafetyError(ThrustmapError):
    """A safety precondition or interlock refused or stopped a motor command."""
