# sagg: set-up, build and entry points.
#
#   make run     set up (if needed), then run the main experiment: sagg run config/arm8.yaml
#   make test    set up (if needed) + the lab tools + the optional Ray extra + the linter, then lint
#                src/ and test/ (ruff, config ruff.toml) and run the test suite
#   make lint    install the linter (requirements-lint.txt) and lint src/ and test/
#   make ray     install the optional Ray extra (requirements-ray.txt) for sagg bench compare --ray
#   make lab     install the lab tools (sagg_lab: sagg bench speed/graph/riac/soak/hostile/quality,
#                python -m sagg_lab.NAME); make test installs them, make run does not
#   make setup   everything but running: .venv + pinned wheels + sagg_msgs + the product's editable packages
#   make msgs    (re)build and install the sagg_msgs interface package into .venv
#   make lock    regenerate requirements.txt (full pinned lock) from requirements.in
#   make clean   remove .venv (including the sagg_msgs build folder) and egg-info folders
#
# Each step leaves a stamp file in .venv, so a second call only redoes what changed:
#   requirements.txt             -> reinstall wheels (then rebuild msgs, reinstall packages)
#   any file under src/sagg_msgs -> rebuild and reinstall sagg_msgs
#   setup.py/setup.cfg/package.xml/resource or a C source (the compiled neighbour searches) of a
#   Python package, or the set of installed launch/config files
#                                -> reinstall the editable Python packages (rebuilding C sources)
# Needs only Python 3.11 (falls back to python3), gcc, cmake and make.

SHELL := /bin/bash
.SHELLFLAGS := -eo pipefail -c
.DEFAULT_GOAL := setup

PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV := .venv
VENV_ABS := $(abspath $(VENV))
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
MSGS_BUILD := $(VENV)/build/sagg_msgs

PY_PKGS := sagg_common sagg_goal_generator sagg_low_level sagg_sim_bridge sagg_bringup
# the measuring tools: a package of their own that the runtime never imports (installed by make lab/test)
LAB_PKGS := sagg_lab
LAB_PKG_META := $(foreach p,$(LAB_PKGS),src/$(p)/setup.py src/$(p)/setup.cfg src/$(p)/package.xml src/$(p)/resource/$(p))
PY_PKG_META := $(foreach p,$(PY_PKGS),src/$(p)/setup.py src/$(p)/setup.cfg src/$(p)/package.xml src/$(p)/resource/$(p))
# compiled sources (setup.py ext_modules): a changed one is rebuilt by the editable reinstall
PY_PKG_C := $(wildcard $(foreach p,$(PY_PKGS),src/$(p)/$(p)/*.c src/$(p)/$(p)/*.h) src/sagg_common/include/*.h)
MSGS_SRCS := $(shell find src/sagg_msgs -type f -not -name '*.pyc' 2>/dev/null | sort)

STAMP_VENV := $(VENV)/.stamp-venv
STAMP_WHEELS := $(VENV)/.stamp-wheels
STAMP_MSGS := $(VENV)/.stamp-msgs
STAMP_PKGS := $(VENV)/.stamp-pkgs
DATA_LIST := $(VENV)/.stamp-datafiles
STAMP_RAY := $(VENV)/.stamp-ray
STAMP_LAB := $(VENV)/.stamp-lab
STAMP_LINT := $(VENV)/.stamp-lint

# Keep ROS 2 discovery on this machine (the default multicasts on every interface).
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: setup msgs run test lock clean ray lab lint FORCE

setup: $(STAMP_MSGS) $(STAMP_PKGS)

msgs: $(STAMP_MSGS)

run: setup
	$(VENV)/bin/sagg run config/arm8.yaml

test: setup $(STAMP_LAB) $(STAMP_RAY) $(STAMP_LINT)
	$(VENV)/bin/ruff check src test
	$(PY) -m pytest -q test/

lint: $(STAMP_LINT)
	$(VENV)/bin/ruff check src test

$(STAMP_LINT): requirements-lint.txt $(STAMP_WHEELS)
	$(PIP) install --no-input -q -r requirements-lint.txt
	@touch $@

lab: $(STAMP_LAB)

$(STAMP_LAB): $(STAMP_PKGS) $(LAB_PKG_META)
	PYTHONWARNINGS=ignore::UserWarning $(PIP) install --no-input -q --no-deps --no-build-isolation $(foreach p,$(LAB_PKGS),-e src/$(p))
	@touch $@

# Optional Ray extra (sagg bench compare --ray); the tests cover that path, `make run` does not need it.
ray: $(STAMP_RAY)

$(STAMP_RAY): requirements-ray.txt $(STAMP_WHEELS)
	$(PIP) install --no-input -r requirements-ray.txt
	@touch $@

$(STAMP_VENV):
	@test -n "$(PYTHON)" || { echo "error: python3.11 (or python3) not found" >&2; exit 1; }
	$(PYTHON) -m venv $(VENV)
	@touch $@

$(STAMP_WHEELS): requirements.txt $(STAMP_VENV)
	$(PIP) install --no-input -r requirements.txt
	@touch $@

# Plain cmake build of the ament_cmake interface package, installed into the venv prefix itself:
# libraries to .venv/lib (on the ROS wheels' library path), Python modules to .venv's
# site-packages, interface files and the ament index to .venv/share. So nothing needs sourcing.
$(STAMP_MSGS): $(STAMP_WHEELS) $(MSGS_SRCS)
	@if [ ! -f $(MSGS_BUILD)/CMakeCache.txt ]; then \
	  echo "configuring sagg_msgs"; mkdir -p $(MSGS_BUILD); \
	  AMENT_PREFIX_PATH=$(VENV_ABS) CMAKE_PREFIX_PATH=$(VENV_ABS) \
	  cmake -S src/sagg_msgs -B $(MSGS_BUILD) \
	    -DCMAKE_INSTALL_PREFIX=$(VENV_ABS) \
	    -DCMAKE_PREFIX_PATH=$(VENV_ABS) \
	    -DPython3_EXECUTABLE=$(VENV_ABS)/bin/python \
	    -DCMAKE_BUILD_TYPE=Release \
	    -DBUILD_TESTING=OFF > $(VENV)/build/sagg_msgs-configure.log 2>&1 \
	  || { cat $(VENV)/build/sagg_msgs-configure.log; rm -f $(MSGS_BUILD)/CMakeCache.txt; exit 1; }; \
	fi
	@echo "building sagg_msgs"
	@AMENT_PREFIX_PATH=$(VENV_ABS) CMAKE_PREFIX_PATH=$(VENV_ABS) \
	  cmake --build $(MSGS_BUILD) -j2 > $(VENV)/build/sagg_msgs-build.log 2>&1 \
	  || { tail -n 60 $(VENV)/build/sagg_msgs-build.log; exit 1; }
	@# Remove what a previous install put there (e.g. a message that was deleted since).
	@if [ -f $(MSGS_BUILD)/install_manifest.txt ]; then xargs -d '\n' rm -f < $(MSGS_BUILD)/install_manifest.txt; fi
	@cmake --install $(MSGS_BUILD) > $(VENV)/build/sagg_msgs-install.log 2>&1 \
	  || { tail -n 30 $(VENV)/build/sagg_msgs-install.log; exit 1; }
	@echo "installed sagg_msgs into $(VENV_ABS)"
	@touch $@

# The set (not the contents) of launch/config files that sagg_bringup installs as data files:
# rewritten only when that set changes, so adding a config reinstalls, editing one does not.
$(DATA_LIST): FORCE $(STAMP_VENV)
	@ls -1 config/*.yaml config/robots/* src/sagg_bringup/launch/*.py 2>/dev/null | sort > $@.tmp || true
	@if cmp -s $@.tmp $@; then rm -f $@.tmp; else mv -f $@.tmp $@; fi

# Editable installs (PEP 660). pip puts the console scripts in .venv/bin; the setup.cfg
# [develop]/[install] script dirs (lib/<pkg>, for `ros2 run`) only apply to colcon/setup.py.
$(STAMP_PKGS): $(STAMP_WHEELS) $(PY_PKG_META) $(PY_PKG_C) $(DATA_LIST)
	@# PYTHONWARNINGS: hide setuptools' generic "editable installation" banner (a UserWarning).
	PYTHONWARNINGS=ignore::UserWarning $(PIP) install --no-input -q --no-deps --no-build-isolation $(foreach p,$(PY_PKGS),-e src/$(p))
	@touch $@

# Regenerate the full lock in a throw-away venv: install requirements.in, then record every
# distribution pip installed (the ROS wheels also carry egg-info folders of their inner Python
# packages, e.g. `rclpy`; those are not PyPI distributions and are left out).
LOCK_PY := import importlib.metadata as m; \
  pins = {d.metadata["Name"] + "==" + d.version for d in m.distributions() \
          if (d.read_text("INSTALLER") or "").strip() == "pip"}; \
  print("\n".join(sorted(pins, key=str.lower)))

lock:
	rm -rf $(VENV)-lock
	$(PYTHON) -m venv $(VENV)-lock
	$(VENV)-lock/bin/python -m pip install --no-input -r requirements.in
	@{ echo "# Full pinned lock generated by 'make lock' from requirements.in; do not edit by hand."; \
	   $(VENV)-lock/bin/python -c '$(LOCK_PY)'; } > requirements.txt
	rm -rf $(VENV)-lock
	@echo "wrote requirements.txt ($$(grep -c '==' requirements.txt) pins)"

clean:
	rm -rf $(VENV) $(VENV)-lock
	rm -rf $(foreach p,$(PY_PKGS) $(LAB_PKGS),src/$(p)/$(p).egg-info src/$(p)/build)
	rm -f $(foreach p,$(PY_PKGS),src/$(p)/$(p)/*.so)

FORCE:
