# Two entry points a fresh machine needs: `make test` and (with the service issue) `make serve`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-dev

.PHONY: install test bench clean system-deps

# gmsh's PyPI wheel links a few X/GL libraries a bare Debian lacks.
GMSH_DEBS := libglu1-mesa libgl1 libxcursor1 libxft2 libxinerama1

system-deps:
	@if ! ldconfig -p | grep -q libGLU.so.1 || ! ldconfig -p | grep -q libXcursor.so.1 \
	   || ! ldconfig -p | grep -q libXft.so.2 || ! ldconfig -p | grep -q libXinerama.so.1; then \
	  echo "installing gmsh's system libraries: $(GMSH_DEBS)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(GMSH_DEBS) >/dev/null; \
	fi

$(STAMP): pyproject.toml
	$(MAKE) system-deps
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) scripts/bench_fem.py

clean:
	rm -rf $(VENV) build *.egg-info
