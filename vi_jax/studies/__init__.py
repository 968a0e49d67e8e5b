"""Studies behind the benchmarks and the command line: accuracy against run time (work precision)."""
