"""The deformation service: a model folder (models/<name>/) answered over HTTP and OpenIGTLink with onnxruntime.

    app.py        the FastAPI app factory; the model is loaded in its lifespan
    settings.py   every setting (a flag or a DEFORM_* variable); cores.py the defaults the cores give
    model.py      the predictor over a model folder; info.py what the service shows of it
    materials.py  a material model's stiffness inputs; guide.py the needle guide's pose
    http.py       the one error reply, content negotiation, the body limit, CORS
    routes.py     GET /model, /mesh, /healthz, /readyz, /metrics; docs.py /docs; viewer.py /viewer
    predict/      POST /predict: routes (parse) -> pipeline (plan -> decode -> reply), batching, export
    estimate/     POST /estimate and /plan: the fit, the aim, their routes
    middleware/   the layers around the routes: access log, auth, admission limits, metrics
    cli/          `python -m service export|estimate|plan`, offline
    igtl.py       the OpenIGTLink server; healthcheck.py the container's health check

The tools that drive a running service (load test, browser) are in tools/, the soak test in bench/: never imported here.
"""
