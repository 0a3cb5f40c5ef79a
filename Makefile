# Two commands on a fresh Debian machine (root): `make run` and `make test`. Each installs what it needs first.
PYTHON ?= python3
PIP := $(PYTHON) -m pip
STAMP := .make
export MUJOCO_GL ?= egl
export PYTHONUNBUFFERED := 1

.PHONY: install system run test bench lint clean

# Debian packages for off-screen GL: EGL (default) and OSMesa (fallback, MUJOCO_GL=osmesa); a virtual X
# display and a key sender for `mjdrive drive`'s test (xvfb, xdotool).
$(STAMP)/system:
	@mkdir -p $(STAMP)
	@if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
	    libegl1 libopengl0 libgl1-mesa-dri libosmesa6 xvfb xdotool >/dev/null; \
	else echo "not root or no apt-get: make sure libegl1 libopengl0 libgl1-mesa-dri (or libosmesa6), xvfb and" \
	  "xdotool are installed"; fi
	@touch $@

# torch first and pinned, then the project. TORCH_INDEX picks the wheel index torch comes from: empty (the
# default) uses pip's own configuration, which resolves to CUDA builds (GBs) where no local CPU wheel exists;
# `make run TORCH_INDEX=https://download.pytorch.org/whl/cpu` gets PyTorch's CPU-only build anywhere.
# The ray extra too: the test suite runs the Ray backends on a local Ray (tests/test_parallel.py); plot
# (matplotlib) for the figure tools (tools.urban_figures, tools.plot_curves, tools.draw_map). Not bench
# (highway-env): only the roundabout speed comparison needs it.
TORCH_INDEX ?=
$(STAMP)/python: pyproject.toml $(STAMP)/system
	$(PIP) install -q torch==2.13.0 $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX))
	$(PIP) install -q -e ".[learn,dev,ray,plot,opendrive]"
	$(PYTHON) -m mjdrive.envs.compile_kernels  # compile the numba kernels once into the user's cache
	@touch $@

install: $(STAMP)/python

run: install
	$(PYTHON) -m mjdrive.cli run --task waypoints/four_routes --episodes 2 --out runs/demo --overwrite

test: install
	$(PYTHON) -m pytest -q

bench: install
	$(PYTHON) -m mjdrive.cli bench --out runs/bench.md

lint:
	ruff check .

clean:
	rm -rf $(STAMP) runs .pytest_cache
