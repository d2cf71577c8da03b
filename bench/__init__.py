"""Benchmarks of the FE, the service, the viewer and OpenIGTLink: `python -m bench --list`."""

# Modules that hold code the commands share, not commands of their own.
LIBRARY_MODULES = ("paper_decoder", "service_targets")
