"""Experiments and benchmarks: the paper reproduction, make bench, process launchers."""
