# Two entry points a fresh machine needs: `make serve` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-dev
SERVE_STAMP := $(VENV)/.installed-service
MODEL ?= models/default
HOST ?= 127.0.0.1
PORT ?= 8000
IMAGE ?= deform-service

.DEFAULT_GOAL := help
.PHONY: help docs docs-serve install serve lint test test-fast bench bench-service bench-service-defaults tradeoff convergence fe-error-taylor-hood graded-mesh linear-validity default-model container-test clean system-deps viewer-assets labelmesh anatomy-table

# gmsh's PyPI wheel links a few X/GL libraries a bare Debian lacks.
GMSH_DEBS := libglu1-mesa libgl1 libxcursor1 libxft2 libxinerama1
# The viewer's browser tests drive Debian's chromium through Playwright (no browser download); its
# WebGL runs on Mesa's llvmpipe through EGL (tools/browser.py: half SwiftShader's CPU a frame).
BROWSER_DEBS := chromium libegl-mesa0 libgl1-mesa-dri
# three.js from npm (viewer/package-lock.json), copied where the service serves it; the copies are committed.
VIEWER_VENDOR := service/static/viewer/vendor
THREE := viewer/node_modules/three

# pygalmesh (CGAL's labelled-image mesher, label-map scenes) builds against CGAL and Eigen headers.
CGAL_DEBS := libcgal-dev libeigen3-dev

system-deps: ## the Debian libraries gmsh's wheel and the viewer's browser tests need (apt-get, when missing)
	@if ! ldconfig -p | grep -q libGLU.so.1 || ! ldconfig -p | grep -q libXcursor.so.1 \
	   || ! ldconfig -p | grep -q libXft.so.2 || ! ldconfig -p | grep -q libXinerama.so.1; then \
	  echo "installing gmsh's system libraries: $(GMSH_DEBS)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(GMSH_DEBS) >/dev/null; \
	fi
	@if ! command -v chromium >/dev/null || ! ldconfig -p | grep -q libEGL_mesa.so.0; then \
	  echo "installing the viewer tests' browser: $(BROWSER_DEBS)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(BROWSER_DEBS) >/dev/null; \
	fi

viewer-assets: ## three.js from npm into service/static/viewer/vendor (committed copies)
	cd viewer && npm ci --no-audit --no-fund
	mkdir -p $(VIEWER_VENDOR)
	cp $(THREE)/build/three.module.js $(THREE)/build/three.core.js $(THREE)/examples/jsm/controls/OrbitControls.js \
	  $(THREE)/LICENSE $(VIEWER_VENDOR)/

$(STAMP): pyproject.toml
	$(MAKE) system-deps
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	touch $(STAMP)

install: $(STAMP) ## create .venv and install everything (the dev extra)

# The service alone needs none of the offline or training stack (no torch, gmsh).
$(SERVE_STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[service]'
	touch $(SERVE_STAMP)

serve: $(SERVE_STAMP) ## install the service alone and serve MODEL (models/default) on HOST:PORT (127.0.0.1:8000)
	$(PY) -m service --model $(MODEL) --host $(HOST) --port $(PORT)

help: ## print every target with what it does
	@awk 'BEGIN {FS = ":[^#]*## "} /^[a-zA-Z][a-zA-Z_-]*:.*## / {printf "  %-22s %s\n", $$1, $$2}' $(firstword $(MAKEFILE_LIST))

# The documentation site (mkdocs.yml): MkDocs and its theme only; the pages render docs/results/ with studies.pages.
DOCS_STAMP := $(VENV)/.installed-docs
SITE ?= site
$(DOCS_STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[docs]'
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP) ## build the documentation site offline into SITE (site/), mkdocs --strict
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --site-dir $(SITE)

docs-serve: $(DOCS_STAMP) ## serve the documentation site on 127.0.0.1:8001, rebuilding on change
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs serve --dev-addr 127.0.0.1:8001

# ruff with pyproject.toml's [tool.ruff] settings: pycodestyle, pyflakes and bugbear, 120 columns.
lint: $(STAMP) ## ruff check: style and likely bugs (pyproject [tool.ruff])
	$(PY) -m ruff check .

test: $(STAMP) lint ## install everything, lint, and run the whole test suite (what CI runs)
	$(PY) -m pytest -q

# The local loop: everything but the minutes-long nonlinear stability runs.
test-fast: $(STAMP) ## the test suite without the slow nonlinear solves
	$(PY) -m pytest -q -m "not slow"

# Studies and benchmarks (`python -m studies --list`, `python -m bench --list`). Each prints what it measured; run one at a time.
RUNS ?= runs/default
# Mesh levels of the contact study (every size times each; ratio 1.3); the glued one stays at three.
SCALES ?= 1.69 1.3 1 0.769
bench: $(STAMP) ## FE timings on the default scene
	MKL_NUM_THREADS=1 $(PY) -m bench fem

bench-service: $(STAMP) ## service latency, throughput and targets: models/default and the 312k-node decoder (built when missing)
	$(PY) -m bench service --publish

bench-service-defaults: $(STAMP) ## the service's default workers, lanes, threads and queue delay against their alternatives
	$(PY) -m bench service-defaults --publish

# Accuracy vs time on the end-to-end error (docs/results/tradeoff.*): $(RUNS) must be a sweep on one level of the
# convergence study ($(CONVERGENCE)) or one of the graded meshes ($(GRADED)), e.g. RUNS=runs/default (the
# default's sweep); the tiny-mesh check builds its two sweeps once.
# The script runs numpy and torch on one thread (reproducible fits); a shared 2-core machine stays usable.
CONVERGENCE ?= docs/results/convergence_taylor_hood.json
GRADED ?= docs/results/graded_mesh.json
tradeoff: $(STAMP) ## accuracy vs time on the end-to-end error (RUNS= a sweep)
	$(PY) -m studies tradeoff --sweep $(RUNS) --offgrid $(RUNS)/offgrid --convergence $(CONVERGENCE) \
	    --graded $(GRADED) --mesh-check runs/tiny_mesh_check --publish

# The grid-convergence studies of both guide-wall models (docs/results/convergence_pointwise.json, docs/results/convergence_glued.json)
# and their comparison (docs/results/contact_vs_glued.json); resumable: run it again to go on.
convergence: $(STAMP) ## grid-convergence studies of both guide models and their comparison (resumable)
	MKL_NUM_THREADS=2 $(PY) -m studies convergence-study --guide contact --step-mm 0.5 --scales $(SCALES) --publish
	MKL_NUM_THREADS=2 $(PY) -m studies convergence-study --guide glued --scales 1.69 1.3 1 --publish
	$(PY) -m studies contact-vs-glued --publish

# The default model's FE error against the Taylor-Hood element's converged estimate (docs/results/fe_error_default.json):
# the study on five contact levels (resumable; each case is judged on the three finest levels that solved it), the
# model against it node by node, then the stamp in models/default (manifest, report.md; the ONNX graph and the mesh
# stay as they are). 20-58 min for the three coarser levels, 85 min for the fourth, 79-141 min a case for the
# fifth (docs site, "Grid convergence"); stop and rerun to resume.
TH_SCALES ?= 1.3 1 0.769 0.5917 0.4552
TH_CASES ?= 10:0 10:10 5:5
TH_NAME ?= convergence_taylor_hood
fe-error-taylor-hood: $(STAMP) ## Taylor-Hood convergence study, models/default against it, restamp (hours; resumable)
	MKL_NUM_THREADS=2 $(PY) -m studies convergence-study --guide contact --step-mm 0.5 --scales $(TH_SCALES) \
	    --volumetric taylor_hood --cases $(TH_CASES) --name $(TH_NAME) --publish
	$(PY) -m studies model-vs-converged --model models/default --study runs/convergence_contact_taylor_hood \
	    --scales $(TH_SCALES) --cases $(TH_CASES) --publish
	$(PY) -m training restamp --model models/default --fe-error docs/results/fe_error_default.json

# Meshes graded where the error is ($(GRADED)): each solves the hard cases (6-9 min here) and is judged
# against the Taylor-Hood study's converged estimate (its folder from fe-error-taylor-hood); resumable.
GRADED_SIZES ?= 15.600000000000001:4:2 15.600000000000001:3.08:2.6 15.600000000000001:5.2:1.54
graded-mesh: $(STAMP) ## meshes graded at the prostate and tip, judged against the converged estimate
	MKL_NUM_THREADS=2 $(PY) -m studies graded-mesh --sizes $(GRADED_SIZES) --scales $(TH_SCALES) --publish

# Up to which displacement the linear model is a deformation (docs/results/linear_validity.json), on the default model's
# scene; 2 min. With its nonlinear sweep in $(RUNS) (default-model's) it compares with it on the same mesh and
# bounds det F of all its snapshots.
linear-validity: $(STAMP) ## up to which push the linear model is a deformation
	$(PY) -m studies linear-validity --scene $(DEFAULT_SCENE) $(if $(wildcard $(RUNS)/manifest.json),--sweep $(RUNS)) --publish

# The committed models/default from scratch: sweep (with du/d ln E of the scene's [materials] tissues), off-grid
# cases (from rest), fit, fresh FE at the ends of the material ranges and the stamp of the first-order material
# model's error against them, then the stamp of its end-to-end error against the Taylor-Hood study's converged
# estimate (fe-error-taylor-hood). Each step resumes. Its scene is fem_offline/scenes/default.toml (Taylor-Hood,
# the tip in contact, 6,810 tets).
DEFAULT_SCENE ?= fem_offline/scenes/default.toml
MATERIAL_CASES ?= --case 10/0 --case 10/10 --case 7.5/0
default-model: $(STAMP) ## rebuild models/default from scratch: sweep, cases, fit, material and FE-error stamps (resumable)
	$(PY) -m fem_offline sweep --scene $(DEFAULT_SCENE) --out $(RUNS)
	$(PY) -m fem_offline cases --scene $(DEFAULT_SCENE) --mesh $(RUNS)/mesh.npz --out $(RUNS)/offgrid --n 8 --seed 0
	$(PY) -m training fit --snapshots $(RUNS) --out models/default --rank 64 --sensitivity-rank 32 --width 120 --offgrid $(RUNS)/offgrid
	$(PY) -m fem_offline material-cases --scene $(DEFAULT_SCENE) --mesh $(RUNS)/mesh.npz --sweep $(RUNS) --out $(RUNS)/materials $(MATERIAL_CASES)
	$(PY) -m training material-check --model models/default --cases $(RUNS)/materials
	$(MAKE) fe-error-taylor-hood

# Build the image with podman (or docker), start it, POST /predict, stop it.
container-test: ## build the image with podman, POST /predict, stop it
	bash scripts/container_test.sh $(IMAGE)

# Label-map meshing (issue #14): CGAL's headers, then pygalmesh built against them (about 11 min).
labelmesh: $(STAMP) ## CGAL and pygalmesh for the default label-map mesher (about 11 min)
	@if ! dpkg -s $(CGAL_DEBS) >/dev/null 2>&1; then \
	  echo "installing CGAL and Eigen headers for pygalmesh: $(CGAL_DEBS)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(CGAL_DEBS) >/dev/null; \
	fi
	$(PY) -m pip install -q -e '.[labelmesh]'

# Marker motion of the three anatomical variants (fem_offline/scenes/anatomy/) at 10 mm, beta = 0, on their
# 1 mm label maps' meshes with the scenes' physics: docs/results/anatomy_table.json (python -m studies anatomy-table; needs
# `make labelmesh`). Each variant's mesh and solve resume: VARIANTS=small runs one.
VARIANTS ?= small medium large
anatomy-table: $(STAMP) ## marker motion of the three anatomical variants (needs labelmesh)
	MKL_NUM_THREADS=2 $(PY) -m studies anatomy-table --variants $(VARIANTS) --publish

clean: ## remove .venv and build outputs
	rm -rf $(VENV) build *.egg-info site
