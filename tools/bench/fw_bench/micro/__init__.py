"""Micro-benchmarks: one piece of fw each, run as `python -m fw_bench.micro NAME`."""
