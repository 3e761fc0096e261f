"""Objects to touch: n-ellipsoids with surface defects, the paper's damaged graphite plate, stroke paths."""

__all__: list[str] = []
