"""fw-bench: the thesis experiments on fw's own deployment (`fw bench`) and the
micro-benchmarks of single pieces (`python -m fw_bench.micro`); docs/bench.md."""
