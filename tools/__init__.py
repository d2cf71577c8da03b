"""Tools that drive a running service from outside: a load generator (`python -m tools.loadtest`) and a browser.

The service never imports them, and they import nothing of the project: bench, studies and the tests use them.
"""
