"""The exit codes of the command line (the module docstring of :mod:`elastoplast.cli.main` says when each is given)."""

EXIT_OK, EXIT_NOT_CONVERGED, EXIT_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 3, 130, 143
#: stdout closed by its reader (``elastoplast ... | head``): the shell's code for SIGPIPE
EXIT_BROKEN_PIPE = 141
