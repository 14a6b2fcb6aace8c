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
