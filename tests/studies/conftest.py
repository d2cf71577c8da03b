"""The tiny scene's fixtures, shared with tests/fem_offline."""

from tests.fem_offline.conftest import tiny_mesh, tiny_problem, tiny_scene  # noqa: F401
