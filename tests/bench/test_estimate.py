"""bench estimate against a served tiny model: uvicorn serves the estimate stream, and every frame gets its reply."""

from bench.estimate import bodies, served, stream
from service.model import Predictor, read_model_folder
from tools import loadtest


def test_the_served_routes_and_the_stream_answer_every_request(tiny_model):
    folder = read_model_folder(tiny_model)
    predictor = Predictor(folder)
    est, plan = bodies(folder, predictor, 4, seed=0)
    with loadtest.local_service("--model", str(tiny_model), "--workers", "1") as url:
        timed = served(url, est, plan)
        frames = stream(url, folder, predictor, 0.5, seed=0)
    assert timed["estimate"]["n"] == 3 and timed["plan"]["n"] == 3  # the first of each opens the connection
    assert frames["frames"] == 15 and frames["lag_n"] == 15
