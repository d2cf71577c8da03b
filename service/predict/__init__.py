"""POST /predict, in the order a request meets it: routes.py parses it (body, Accept, ?format=), pipeline.py plans,
decodes and replies, with decode.py's numerics, batching.py's batcher and replies.py's bodies; export.py writes the
mesh files of ?format=. schemas.py holds the request and reply models built from the loaded model."""
