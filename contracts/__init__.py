"""The files between the stages, each format owned once: the tet10 node order, the sweep folder and the model folder.

Needs only numpy and pydantic, so the service imports it without the offline or training stack.
"""
