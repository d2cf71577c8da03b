"""Geometry: the phantom's shapes, gmsh meshing, the tet mesh and its I/O, the named node sets (regions, the guide's
patch) and the x = 0 mirror."""
