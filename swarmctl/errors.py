"""Errors that cross the project's boundaries.

`InputError` is the one exception for bad outside input (CLI arguments, mission and area files,
checkpoints). Its message is a single line that names the file or field and says how to fix it;
the CLI prints it and exits with status 2, never with a traceback.
"""

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


class InputError(Exception):
    """Bad outside input: the message names the file/field and the fix."""


class ScenarioError(InputError):
    """A scenario that cannot be generated with the requested parameters."""


def printable(text: str) -> str:
    """Text from outside (a vehicle's STATUSTEXT, a name read from a file), safe to print on a
    terminal: each character that is not printable (an escape that would move the cursor or retitle the
    window, a bidirectional override that would reorder what is shown) written as its Python escape."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in text)
