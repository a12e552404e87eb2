#!/usr/bin/env bash
# Reports where a CTest run's time went (the slowest tests, totals).
#
# The slowest tests of a CTest run and its totals, from the log `ctest ... | tee LOG` wrote: a
# report of where the suite's time goes (.ci/run prints it at its end), never a gate.
#
#   bash .ci/ctest-report.sh LOG [COUNT]     (COUNT slowest, default 15)
set -euo pipefail
log=$1 count=${2:-15}
[ -f "$log" ] || { echo "ctest-report: no such log: $log" >&2; exit 1; }
# "12/775 Test #34: name .....   Passed    1.23 sec"
times=$(sed -nE 's/^ *[0-9]+\/[0-9]+ +Test +#[0-9]+: ([^ ]+) .* ([0-9]+\.[0-9]+) sec$/\2 \1/p' "$log" | sort -rn)
echo "The $count slowest tests of $log:"
printf '%s\n' "$times" | head -n "$count" | awk '{printf "  %8.2f s  %s\n", $1, $2}'
printf '%s\n' "$times" | awk '{s += $1; n++} END {printf "  %d tests, %.0f s of test time in all\n", n, s}'
grep -E '^Total Test time \(real\)' "$log" | sed 's/^/  /' || true
