# Monte: `make render` renders the Cornell box, installing (the first time) only what a render needs, with the
# Cornell box's compiled kernels shipped in kernels/; `make setup` sets everything up and `make test` runs the tests.
# Setting up compiles every render kernel once (numba's cache: core/precompile.py), so renders start at once; a
# render before that compiles the kernels it calls that the cache does not hold.
#
# Environments, one per Blender version (PyPI's bpy module pins the Python it runs on):
#   .venv      Blender 5.3 (bpy 5.3.0, Python 3.13, numpy 2.x): the default for everything below
#   .venv-5.0  Blender 5.0 (bpy 5.0.1, Python 3.11, numpy 1.26)
#   .venv-4.5  Blender 4.5 LTS (bpy 4.5.15, Python 3.11)
#   .venv-4.2  Blender 4.2 LTS (bpy 4.2.23, Python 3.11)
# Python is found on PATH or through pyenv (tools/find_python.sh); PYTHON=/path/to/python3.13 overrides the
# default environment's interpreter.
PYTHON ?= $(shell tools/find_python.sh 3.13)
PYTHON311 ?= $(shell tools/find_python.sh 3.11)
VENV := .venv
BIN := $(VENV)/bin
SPP ?= 64
OLDER_BLENDERS := 4.2 4.5 5.0
BLENDERS := $(OLDER_BLENDERS) 5.3

.PHONY: setup render render-kernels test test-newest test-install-matrix test-blender test-slow test-all bench crosscheck \
        extension clean

# $(call install,DIR,PYTHON,REQUIREMENTS): the venv DIR (made with PYTHON if missing), REQUIREMENTS and Monte
# itself (editable, in place of the link the render set's quick install may have made). A venv that quick install
# made has no pip of its own: it gets one here.
define install
	@test -n "$(2)" || { echo "no Python interpreter for $(1) (see the message above)"; exit 1; }
	test -x $(1)/bin/python || $(2) -m venv $(1)
	$(1)/bin/python -c "import pip" 2> /dev/null || $(1)/bin/python -m ensurepip --upgrade --default-pip > /dev/null
	$(1)/bin/python -m pip install --quiet --upgrade pip
	$(1)/bin/python -m pip install --quiet -r $(3)
	link="$$($(1)/bin/python -P -c 'import sysconfig; print(sysconfig.get_path("purelib"))')/monte"; \
	  if [ -L "$$link" ]; then rm "$$link"; fi
	$(1)/bin/python -m pip install --quiet --no-deps -e .
endef

# $(call make_venv,DIR,PYTHON,REQUIREMENTS): installed as above, the bytecode of what the render set's quick
# install left uncompiled (a process with PYTHONDONTWRITEBYTECODE set would compile those modules at every start;
# errors are ignored, as pip ignores them), then every render kernel compiled
define make_venv
	$(call install,$(1),$(2),$(3))
	$(1)/bin/python -m compileall -q -j 0 $$($(1)/bin/python -c 'import sysconfig; print(*{sysconfig.get_path(p) for p in ("purelib", "platlib")})') > /dev/null || true
	$(1)/bin/python -m monte.core.precompile
	touch $(1)/.installed
endef

# (after the render set, so that `make -j` never runs two pip installs into .venv at once; and after the shipped
# kernels, which the precompile then loads instead of compiling: order-only, so that a rebuilt archive does not
# redo the whole setup)
$(VENV)/.installed: $(VENV)/.render-installed requirements.txt requirements/blender-5.3.txt requirements/common.txt \
                    pyproject.toml | $(VENV)/.render-kernels
	$(call make_venv,$(VENV),$(PYTHON),requirements.txt)

# The render set alone (requirements/render.txt: Blender 5.3's numpy and the core's pins; no Blender, tests,
# cluster or denoiser), which is all a built-in scene's render imports: the first `make render` after a clone
# waits for this (and the shipped kernels' unpacking), not for the whole setup.
$(VENV)/.render-installed: requirements/render.txt requirements/core.txt pyproject.toml
	@test -n "$(PYTHON)" || { echo "no Python interpreter for $(VENV) (see the message above)"; exit 1; }
	tools/install_render_set.sh $(VENV) $(PYTHON) requirements/render.txt
	touch $@

# The Cornell box's compiled kernels, shipped in the repository (kernels/render-set.tar.xz, tools/render_kernels.py):
# put into the kernel cache, so that the first `make render` loads them instead of compiling them. Where they do not
# apply (another CPU level, Python or numba, or kernels edited since), it says so and the render compiles.
$(VENV)/.render-kernels: $(VENV)/.render-installed kernels/render-set.tar.xz
	$(BIN)/python tools/render_kernels.py unpack
	touch $@

# After editing a kernel module: rebuild the shipped kernels (tests/test_render_kernels.py fails until then).
render-kernels: $(VENV)/.render-installed
	$(BIN)/python tools/render_kernels.py build

.venv-%/.installed: requirements/blender-%.txt requirements/common.txt requirements/core.txt pyproject.toml
	$(call make_venv,.venv-$*,$(PYTHON311),requirements/blender-$*.txt)

setup: $(VENV)/.installed

render: $(VENV)/.render-kernels
	$(BIN)/python -m monte render cornell -o cornell.exr --spp $(SPP)

# What CI runs: the default suite on Blender 5.3, then the extension's install-and-render and headless-exit
# tests on every older Blender of the support table.
test: test-newest test-install-matrix

test-newest: $(VENV)/.installed
	$(BIN)/python -m pytest -m "not slow" -q

test-install-matrix: $(foreach v,$(OLDER_BLENDERS),.venv-$(v)/.installed)
	@set -e; for v in $(OLDER_BLENDERS); do \
	  echo "== Blender $$v: install, render, exit"; \
	  .venv-$$v/bin/python -m pytest -m "matrix" -q -p no:cacheprovider; \
	done

# Every Blender-facing test and the default Cycles cross-checks, on each Blender version in turn (about
# 10 minutes a version on 2 cores).
test-blender: $(VENV)/.installed $(foreach v,$(OLDER_BLENDERS),.venv-$(v)/.installed)
	@set -e; for v in $(BLENDERS); do \
	  py=.venv-$$v/bin/python; [ "$$v" = 5.3 ] && py=$(BIN)/python; \
	  echo "== Blender $$v: Blender-facing tests and Cycles cross-checks"; \
	  $$py -m pytest -m "blender and not slow" -q -p no:cacheprovider; \
	done

test-slow: $(VENV)/.installed
	$(BIN)/python -m pytest -m slow -q

test-all: $(VENV)/.installed
	$(BIN)/python -m pytest -q

bench: $(VENV)/.installed
	$(BIN)/monte bench

# The feature-by-feature Cycles cross-check at 64x64 and 4x the samples of the default suite's (about 20 min
# on 2 cores).
crosscheck: $(VENV)/.installed
	$(BIN)/python -m pytest tests/test_crosscheck.py -m slow -q -rA

# The zips for this machine's platform carry the compiled kernels for Python 3.13 and, when .venv-5.0 exists
# (make .venv-5.0/.installed), for Python 3.11 (Blender 4.2 - 5.0) too.
extension: $(VENV)/.installed
	$(BIN)/python tools/build_extension.py $(if $(wildcard .venv-5.0/bin/python),--kernel-python .venv-5.0/bin/python)

clean:
	rm -rf $(VENV) $(foreach v,$(OLDER_BLENDERS),.venv-$(v)) dist build *.egg-info cornell.exr cornell.png
