"""Studies of the physics and the surrogate: `python -m studies --list`; each writes runs/results/ unless --publish."""

# Modules that hold code the commands share, not commands of their own.
LIBRARY_MODULES = ("results", "convergence", "meshers", "pages", "options", "stepping", "phantom_labelmap")
