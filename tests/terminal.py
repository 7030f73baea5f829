"""A stand-in terminal for progress-bar tests: a text stream that says it is a TTY, and the lines a
real terminal would show after the carriage returns in what was written to it."""

from __future__ import annotations

import io


class Terminal(io.StringIO):
    """Collects what is written, and answers ``isatty()`` with True as a console would."""

    def isatty(self) -> bool:
        return True


def screen_lines(text: str) -> list[str]:
    """The non-blank lines left on screen: ``\\r`` returns to column 0 and the next text overwrites."""
    lines = []
    for written in text.split("\n"):
        shown = ""
        for piece in written.split("\r"):
            shown = piece + shown[len(piece) :]
        if shown.strip():
            lines.append(shown.rstrip())
    return lines
