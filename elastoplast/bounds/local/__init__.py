"""The local lower bound: an exactly admissible stress field built from the P1 solution
without a global program (``construction.local_lower_bound``).

Its rooms, in the order the construction uses them: ``contact`` (the contact pressure and
the layer next to Γ0), ``equilibrate`` (facet tractions star by star), ``lift`` (the exact
lift into each element's barycentric split), ``energy`` (the element complementary energy
J_e, its gradient and the yield normals, and the element imbalance), ``rings`` (ring
patches and their batches), ``state`` (the sweeps' frozen, typed state), ``sweeps`` (the
coloured ring sweeps and the round-off repair), ``descent`` (L-BFGS over all rings
together), ``kernel`` and ``kernel_bases`` (the compiled ring Newton step and the
compiled energy and gradient)."""
