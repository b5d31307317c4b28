"""Studies: many solves run, stored and compared, below the command line.

Campaigns (sweeps of reference solutions on Dask, kept in the store of
:mod:`elastoplast.io.store`), comparisons of a method against the stored references,
suites of problem files with their performance profiles, and the files a solve
writes (``summary.json``, ``solution.vtu``, the convergence plot). The command line
parses the arguments and prints; these modules do the work and return values."""
