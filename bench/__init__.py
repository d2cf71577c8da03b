"""Benchmarks of the FE, the service, the viewer and OpenIGTLink: `python -m bench --list`."""
