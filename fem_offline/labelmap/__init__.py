"""Segmentation label maps: I/O (NIfTI, NRRD), surface nets, the tet meshers (CGAL, TetGen, fTetWild) and quality
checks. The voxelised-phantom fixture the tests and studies use is studies/phantom_labelmap.py."""
