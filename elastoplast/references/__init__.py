"""Solve, then bound: the layer between the bounds (computed from given solutions) and the
adaptive loop. :mod:`.solves`, the P1 solves the bounds ask for (the conservative
obstacle's, other loads', a tighter tolerance's); :mod:`.certified`, a problem's energy and
U brackets from its solution (:func:`~.certified.certified_bounds`)."""
