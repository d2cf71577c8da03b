"""Where /predict decodes: the node sets cheap enough for the event loop, measured at start."""

from service.predict.pipeline import cheap_keys
from service.predict.decode import ALL_NODES


def test_cheap_keys_are_the_node_sets_decoded_within_the_budget(predictor):
    every = {ALL_NODES, *(f"region:{name}" for name in predictor.folder.regions)}
    assert cheap_keys(predictor, 0.0) == frozenset()
    assert cheap_keys(predictor, 10.0) == every  # a 10k-node decode takes about half a millisecond
    assert cheap_keys(predictor, 1e-6) == frozenset()  # no decode is that fast
