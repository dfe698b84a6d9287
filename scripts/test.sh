#!/usr/bin/env bash
# Set up the environment if needed, then run the whole test suite (pytest).
# Extra arguments go to pytest, e.g. scripts/test.sh -k fusion -x
# The files run in TL_TEST_WORKERS parallel processes (pytest-xdist; default 2, 0 = in this
# process); each process has a ROS_DOMAIN_ID of its own (test/conftest.py). Whole files go to the
# workers in collection order, which test/conftest.py starts with the longest files.
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck disable=SC1091
source scripts/setup_env.sh
exec python -m pytest test -q -p no:cacheprovider -n "${TL_TEST_WORKERS:-2}" --dist loadfile --no-loadscope-reorder "$@"
