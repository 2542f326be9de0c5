# Shared set-up of tools/demo and tools/check: a virtual environment in .venv with wcut
# installed (editable) and its test dependencies. Needs only python3 (>= 3.10) on the machine.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
if [ ! -x .venv/bin/python ]; then
  echo "creating .venv ..." >&2
  python3 -m venv .venv
fi
stamp=.venv/.wcut-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "installing wcut and its dependencies into .venv ..." >&2
  .venv/bin/python -m pip install --quiet --disable-pip-version-check --upgrade pip
  .venv/bin/python -m pip install --quiet --disable-pip-version-check -e ".[test,plot]"
  touch "$stamp"
fi
export PATH="$root/.venv/bin:$PATH"
