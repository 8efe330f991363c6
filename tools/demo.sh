#!/usr/bin/env bash
# README command 1: install the runtime dependencies (tools/setup.sh, no test-only packages),
# then track and score the shipped sample recording and write the figures and tables to out/demo.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
exec .venv/bin/fusion-pf demo --out out/demo "$@"
