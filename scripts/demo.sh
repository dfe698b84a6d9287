#!/usr/bin/env bash
# Set up the environment if needed (first run: a few minutes), then run the demo:
# simulator + sensor nodes + fusion as separate processes, recorded to an MCAP bag,
# then a summary of fused-vs-truth errors. Extra arguments go to tl_demo.
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck disable=SC1091
source scripts/setup_env.sh
exec python -m train_localization.tools.demo "$@"
