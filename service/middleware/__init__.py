"""The layers around the routes (service/app.py adds them): the JSON access log, bearer-token auth, admission (rate
limit, the cap on /predict requests) and Prometheus metrics."""
