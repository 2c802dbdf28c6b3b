"""Benchmarks: each ``bench_*.py`` is a script printing one JSON object of figures."""
