"""Benchmarks on the simulator: the episode runner and store, the marker baseline, the fixed camera poses."""
