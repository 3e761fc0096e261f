"""Geometry: n-ellipsoids (eq. 2, 4–6), meshes and sampling, surface integrals (eq. 11–13), FFD (eq. 9–10)."""

__all__: list[str] = []
