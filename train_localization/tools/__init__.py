"""Command-line tools: demo, offline replay and report, benchmarks."""
