#!/usr/bin/env bash
# README command 2: install everything (tools/setup.sh --test), lint and type-check, then run the test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh --test
.venv/bin/ruff check fusion_pf drivers tests benchmarks
.venv/bin/ruff format --check fusion_pf drivers tests benchmarks
.venv/bin/mypy
exec .venv/bin/python -m pytest -n 2 "$@"
