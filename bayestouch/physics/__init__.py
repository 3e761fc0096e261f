"""Physics of the finger (SMA wires, bending), the auxetic skin (contact, pressure, patch) and the
piezotronic taxels (current, noise): pure JAX functions of arrays and frozen parameter NamedTuples.
See ``docs``: physics.md in the shared design folder; equation numbers are the paper's."""
