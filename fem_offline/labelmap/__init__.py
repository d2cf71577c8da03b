"""Segmentation label maps: I/O (NIfTI, NRRD), surface nets, the tet meshers (CGAL, TetGen, fTetWild), quality
checks and the voxelised-phantom fixtures the tests and studies use."""
