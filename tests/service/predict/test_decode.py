"""The pure predict(): what each kind of request decodes, without HTTP."""

import numpy as np
import pytest

from service.model import OutsideMesh
from service.predict.decode import predict


def test_region_gives_its_nodes_rows_of_the_full_decode(predictor, request_model):
    full = predict(predictor, request_model(displacement_mm=5.0, angle_deg=2.0))
    markers = predict(predictor, request_model(displacement_mm=5.0, angle_deg=2.0, region="markers"))
    ids = predictor.folder.regions["markers"]
    assert full.node_ids is None and full.displacements is None and markers.region == "markers"
    np.testing.assert_array_equal(markers.node_ids, ids)
    # float32 GEMMs of another shape may sum in another order: equal to a few ulp (4.8e-7 mm at rank 64)
    np.testing.assert_allclose(markers.positions, full.positions[ids], rtol=0, atol=1e-5)
    np.testing.assert_allclose(markers.displacements, full.positions[ids] - predictor.nodes32[ids], atol=1e-5)


def test_a_point_outside_the_mesh_raises_naming_the_first_one(predictor, request_model):
    lumen = [0.0, -21.0, 40.0]  # inside the bounding box, in the rectal lumen: no tet
    body = request_model(displacement_mm=5.0, angle_deg=2.0, points=[[0.0, 0.0, 35.0], lumen, lumen])
    with pytest.raises(OutsideMesh) as err:
        predict(predictor, body)
    assert err.value.index == 1 and err.value.point == lumen
