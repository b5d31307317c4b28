"""Figures: the library's only user of matplotlib.

Gap curves and indicator maps of the adaptive loop, comparison and performance-profile
charts, convergence histories and loading-path curves. Each function draws what it is
given and writes a PNG (or draws on a matplotlib axis a notebook passes in)."""
