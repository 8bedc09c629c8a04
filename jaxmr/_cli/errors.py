"""What a command ends with other than success: `CLIError` and the exit statuses.

Its own module, imported by every other module of the command line and importing none
of them, so that the commands and `main` share it without an import cycle.
"""

# The exit status of a command stopped by Ctrl-C (the shell's 128 + SIGINT).
INTERRUPTED = 130


class CLIError(Exception):
    """A failure the user can fix (a bad path, ...): printed without a traceback."""
