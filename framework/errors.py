"""Error types shared by every fw loader, validator and tool.

Every user-facing error carries a location (file, line, column, YAML path) so
the CLI can print it as one line and exit 1 instead of showing a traceback.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_UNPRINTABLE = re.compile("[\x00-\x1f\x7f-\x9f\u200e\u200f\u202a-\u202e\u2066-\u2069]")


def printable(text: str) -> str:
    """`text` with every control character escaped (`\\x1b`, `\\n`, `\\u202e`): what a
    message quotes from a user's file or a peer must not move the cursor, recolour
    the terminal or reverse the text the operator reads, nor break its one line."""
    return _UNPRINTABLE.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), text)


@dataclass(frozen=True, slots=True)
class Location:
    """Where something was written: file, 1-based line and column, YAML path."""

    file: str = "<string>"
    line: int = 0
    column: int = 0
    path: str = ""

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}:{self.column}" if self.line else self.file
        return printable(f"{where}: {self.path}" if self.path else where)


class FwError(Exception):
    """Base of every error fw reports to a user (never shown as a traceback)."""


class LocatedError(FwError):
    """An error in a user's file, printed as `file:line:col: path: message`."""

    def __init__(self, message: str, location: Location | None = None, hint: str = ""):
        self.message = message
        self.location = location or Location()
        self.hint = hint
        super().__init__(self.one_line())

    def one_line(self) -> str:
        """The error as the single line the CLI prints."""
        text = f"{self.location}: {self.message}"
        return printable(f"{text} (hint: {self.hint})" if self.hint else text)


class YamlError(LocatedError):
    """The file is not well-formed YAML, or uses a construct fw refuses."""


class MissingFileError(YamlError):
    """A file that is not there (as opposed to one that is there and wrong)."""


@dataclass(frozen=True, slots=True)
class Finding:
    """One defect found in a user's file, with where it is and how to fix it."""

    severity: str  # "error" or "warning"
    code: str
    message: str
    location: Location
    hint: str = ""

    def one_line(self) -> str:
        """`file:line:col: path: severity[code]: message (hint: ...)`."""
        text = f"{self.location}: {self.severity}[{self.code}]: {self.message}"
        return printable(f"{text} (hint: {self.hint})" if self.hint else text)

    def as_dict(self) -> dict[str, object]:
        """The finding as JSON-ready data (for `--json`)."""
        loc = self.location
        return {
            "severity": self.severity,
            "code": self.code,
            "message": self.message,
            "file": loc.file,
            "line": loc.line,
            "column": loc.column,
            "path": loc.path,
            "hint": self.hint,
        }


class FindingsError(FwError):
    """A file has errors; carries every finding, not just the first."""

    def __init__(self, findings: list[Finding]):
        self.findings = findings
        errors = [f for f in findings if f.severity == "error"]
        first = errors[0].one_line() if errors else "invalid file"
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        super().__init__(first + more)
