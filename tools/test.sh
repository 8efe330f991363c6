#!/usr/bin/env bash
# README command 2: install everything (tools/setup.sh --test), then run the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh --test
exec .venv/bin/python -m pytest -n 2 "$@"
