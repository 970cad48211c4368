#!/usr/bin/env bash
# Print the path of a CPython X.Y interpreter: `pythonX.Y` on PATH, else one that pyenv installed.
# Used by the Makefile: bpy 5.3 needs Python 3.13, bpy 4.2-5.0 need Python 3.11 (PyPI's bpy wheels say so).
set -u
want=${1:?usage: find_python.sh X.Y}
is_version() { "$1" -c "import sys; sys.exit(0 if '%d.%d' % sys.version_info[:2] == '$want' else 1)" 2>/dev/null; }
candidates=()
c=$(command -v "python$want" 2>/dev/null) && candidates+=("$c")
root=$(pyenv root 2>/dev/null || echo "${PYENV_ROOT:-$HOME/.pyenv}")
for d in "$root"/versions/"$want"*/bin/python"$want"; do [ -x "$d" ] && candidates+=("$d"); done
for c in "${candidates[@]}"; do
  if is_version "$c"; then echo "$c"; exit 0; fi
done
cat >&2 <<MSG
Monte needs Python $want here and found none (looked for python$want on PATH and in $root/versions/).
Install it, e.g. \`pyenv install $want\`, your distribution's python$want package, or python.org's
installer; or name one explicitly: \`make ... PYTHON=/path/to/python$want\`.
MSG
exit 1
