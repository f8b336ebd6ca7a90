"""The benchmark suite (`benchmarks/bench_suite.py`, `grazejax bench`), one module per part."""
