#!/bin/sh
# Runs a Python test helper with the venv's interpreter. $1 is the interpreter CMake
# was configured with; the environment variable VIBID_PYTHON overrides it. A missing
# interpreter is a test FAILURE (exit 1) with the command that fixes it, never a skip.
py=${VIBID_PYTHON:-$1}
shift
if [ ! -x "$py" ]; then
  echo "FAIL: Python venv interpreter '$py' not found." >&2
  echo "      Create it with scripts/python-venv.sh (or configure -DVIBID_PYTHON=...)." >&2
  exit 1
fi
exec "$py" "$@"
