"""model_info: what the service shows of its model folder."""

from dataclasses import replace

import numpy as np

from service.info import model_info
from service.model import read_model_folder


def test_bounds_hold_the_float32_nodes_that_get_mesh_sends(settings):
    """GET /mesh sends float32 nodes; rounded outwards they must still pass the points' range check."""
    folder = read_model_folder(settings.model)
    # float32(x + 0.01) rounds below x + 0.01 on some axes
    shifted = replace(folder, mesh=replace(folder.mesh, nodes=folder.nodes + 0.01))
    lo, hi = model_info(shifted, settings).bounds_mm
    nodes32 = shifted.nodes.astype(np.float32)
    assert (nodes32.min(axis=0) >= lo).all() and (nodes32.max(axis=0) <= hi).all()
