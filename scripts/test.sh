#!/usr/bin/env bash
# Set up the environment if needed, then run the whole test suite (pytest).
# Extra arguments go to pytest, e.g. scripts/test.sh -k fusion -x
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck disable=SC1091
source scripts/setup_env.sh
exec python -m pytest test -q -p no:cacheprovider "$@"
