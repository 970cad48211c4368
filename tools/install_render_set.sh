#!/usr/bin/env bash
# The first `make render`'s install: the render set into a venv, and Monte importable from this checkout, in as
# few seconds as pip allows (the clone-to-image time of issue 20; docs/performance.md, "third part").
#
#   tools/install_render_set.sh VENV PYTHON REQUIREMENTS
#
# - A new venv is made without pip (0.05 s instead of ~2-3 s for seeding pip into it) where PYTHON's own pip can
#   install into it (`pip --python`, pip 22.3 or newer); `make setup` adds pip to the venv later (ensurepip).
#   Otherwise the venv gets its own pip, upgraded only where older than 22.
# - The packages' bytecode is left to their first import (--no-compile: pip compiling every module of numpy,
#   numba and llvmlite was 6 of the 9.5 s their install took); `make setup` compiles the rest.
# - Monte itself: a link named `monte` in the venv's site-packages to this checkout (the repository root is the
#   package), instead of an editable install, which builds a wheel in an isolated environment (~2-4 s). `make
#   setup` replaces the link with the editable install, which also writes the `monte` command; until then
#   `python -m monte` runs it. Nothing is linked where Monte is installed already.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
venv=${1:?usage: install_render_set.sh VENV PYTHON REQUIREMENTS}
python=${2:?usage: install_render_set.sh VENV PYTHON REQUIREMENTS}
requirements=${3:?usage: install_render_set.sh VENV PYTHON REQUIREMENTS}

# PYTHON's pip can install into another interpreter's environment (pip 22.3 added --python); asked once (an
# interpreter start, ~25 ms)
base_pip_answer=
base_pip_installs_into_venvs() {
  if [ -z "$base_pip_answer" ]; then
    if "$python" -c "import sys, pip; sys.exit(tuple(map(int, pip.__version__.split('.')[:2])) < (22, 3))" \
        2>/dev/null; then
      base_pip_answer=yes
    else
      base_pip_answer=no
    fi
  fi
  [ "$base_pip_answer" = yes ]
}

if [ ! -x "$venv/bin/python" ]; then
  if base_pip_installs_into_venvs; then
    "$python" -m venv --without-pip "$venv"
  else
    "$python" -m venv "$venv"
  fi
fi

if "$venv/bin/python" -c "import pip" 2>/dev/null; then
  "$venv/bin/python" -c "import sys, pip; sys.exit(int(pip.__version__.split('.')[0]) < 22)" \
    || "$venv/bin/python" -m pip install --quiet --upgrade pip
  pip=("$venv/bin/python" -m pip)
elif base_pip_installs_into_venvs; then
  pip=("$python" -m pip --python "$venv/bin/python")
else
  "$venv/bin/python" -m ensurepip --upgrade --default-pip > /dev/null
  pip=("$venv/bin/python" -m pip)
fi
"${pip[@]}" install --quiet --no-compile -r "$requirements"

# -P: the working folder (this checkout, with a possible monte.egg-info) is not searched for the distribution
if ! "$venv/bin/python" -P -c "import importlib.metadata as m; m.distribution('monte')" 2> /dev/null; then
  site=$("$venv/bin/python" -P -c 'import sysconfig; print(sysconfig.get_path("purelib"))')
  ln -sfn "$root" "$site/monte"
fi
