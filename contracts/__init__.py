"""The files between the stages, each format owned once: the scene, the tet10 node order, the sweep folder and the model
folder.

Needs only numpy and pydantic, so the service imports it without the offline or training stack.

    scene/       the scene a user states and every artifact records: schema, anatomy checks, sha256
    tet10.py     the 10-node tet: node order, edges, faces, P2 shape functions
    mesh.py      TetMesh and its .npz file (nodes, tets, tissues, named node sets)
    envelope.py  the (displacement, angle) envelope a sweep covers and a model answers for
    sweep.py     the sweep folder (fem_offline -> training): SweepManifest, snapshot files
    model.py     the model folder (training -> service): ModelManifest, FitOptions, reader and writer
    files.py     sha256 and atomic writes
"""
