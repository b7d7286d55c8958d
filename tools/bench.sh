#!/usr/bin/env bash
# make bench: every benchmark in bench/, one after the other (each prints its own table).
set -eo pipefail
ROOT=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")/.." && pwd -P)
for b in "$ROOT"/bench/[!_]*.py; do
  echo "=== $(basename "$b") ==="
  python "$b"
done
