"""Benchmarks (BENCHMARKS.md): scripts that print JSON with machine info, parameters, medians and p99s,
and measure each baseline in the same run."""
