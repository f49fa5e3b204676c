#!/usr/bin/env bash
# `make test` several times in a row beside other CPU-bound processes (issue 33's figure:
# three passes in a row on a loaded machine, two other CPU-bound processes running).
# Prints each pass's exit status, wall time and pytest's last line; ends the hogs it starts.
#
#     CI=true bash benchmarks/loaded_tests.sh [passes, default 3] [hogs, default 2]
set -uo pipefail
cd "$(dirname "$0")/.."
passes=${1:-3}
hogs=()
for _ in $(seq "${2:-2}"); do
  yes > /dev/null &
  hogs+=($!)
done
trap 'kill "${hogs[@]}" 2> /dev/null' EXIT
failed=0
for pass in $(seq "$passes"); do
  log=$(mktemp)
  began=$(date +%s)
  echo "pass $pass: started $(date -u +%T), load $(cut -d' ' -f1-3 /proc/loadavg)"
  make test > "$log" 2>&1
  status=$?
  echo "pass $pass: exit $status after $(( $(date +%s) - began )) s;" \
       "$(grep -E '[0-9]+ (passed|failed)' "$log" | tail -1)"
  [ "$status" -eq 0 ] || { failed=1; echo "  its output: $log"; continue; }
  rm -f "$log"
done
exit "$failed"
