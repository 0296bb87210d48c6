#!/usr/bin/env bash
# Breaks the code on purpose (scripts/mutations.json) and reports which mutation no test caught.
# Usage: scripts/mutation_check.sh [--only ID,...] [--out docs/testing.md]   (make mutation)
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install_deps.sh >/dev/null
exec python3 scripts/mutation_check.py "$@"
