"""The global lower bound: the equilibrium element's conic program (:mod:`.program`), the
exact repair of a solver's answer onto its equality rows (:mod:`.repair`), and the
driver that solves, repairs and certifies it (:mod:`.bound`: :func:`solve_lower_bound`,
and with H = 0 the static limit load, :func:`static_limit_load`)."""
