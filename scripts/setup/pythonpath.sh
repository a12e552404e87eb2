#!/usr/bin/env bash
# Prints the repository's Python roots as one PYTHONPATH value.
#
# pytest.ini's `pythonpath`, made absolute, for scripts that run its modules or test helpers as programs of their own:
#   export PYTHONPATH="$(bash scripts/setup/pythonpath.sh)${PYTHONPATH:+:$PYTHONPATH}"
# (The tools, converter/spar-convert and the like, find their roots by themselves.)
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
roots=$(sed -n 's/^pythonpath *= *//p' "$root/pytest.ini")
[ -n "$roots" ] || { echo "pythonpath.sh: no pythonpath line in $root/pytest.ini" >&2; exit 1; }
out=""
for r in $roots; do out="$out${out:+:}$root/$r"; done
echo "$out"
