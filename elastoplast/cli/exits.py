"""The exit codes of the command line (the module docstring of :mod:`elastoplast.cli.main` says when each is given)."""

import sys

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 3, 130, 143
#: stdout closed by its reader (``elastoplast ... | head``): the shell's code for SIGPIPE
EXIT_BROKEN_PIPE = 141


def outcome(ok: bool, why: str) -> int:
    """A command's exit code from its verdict: ``EXIT_OK``, or ``EXIT_NOT_CONVERGED``
    after saying ``why`` on stderr (``"not converged: ..."``, ``"not certified: ..."``)."""
    if ok:
        return EXIT_OK
    print(why, file=sys.stderr)
    return EXIT_NOT_CONVERGED
