"""Geometry: the phantom's shapes, gmsh meshing, the tet mesh and its I/O, tissue regions and the x = 0 mirror."""
