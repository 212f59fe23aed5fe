#!/usr/bin/env bash
# A deliberately wrong cellforce for testing validation/parity.py itself: it runs the real
# executable ($CELLFORCE_REAL) with every --cutoff shortened by 1%, which drops the pairs between
# 0.99 rc and rc. parity.py must report those rows as failed and exit 1 (tests/CMakeLists.txt).
set -euo pipefail
real=${CELLFORCE_REAL:?set CELLFORCE_REAL to the real cellforce executable}
args=()
while [ $# -gt 0 ]; do
  if [ "$1" = --cutoff ] && [ $# -ge 2 ]; then
    args+=(--cutoff "$(awk -v c="$2" 'BEGIN { printf "%.17g", 0.99 * c }')")
    shift 2
  else
    args+=("$1")
    shift
  fi
done
exec "$real" "${args[@]}"
