"""Physics of the finger (SMA wires, bending), the auxetic skin (contact, pressure, patch) and the
piezotronic taxels (current, noise): pure JAX functions of arrays and frozen parameter NamedTuples, SI units.
Derivations and sources: ``docs/physics_notes.md`` (which cites the shared design reference physics.md by section);
equation numbers are the paper's."""

__all__: list[str] = []
