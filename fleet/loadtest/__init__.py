"""Load tests (``fleet loadtest``): a generated warehouse for N robots, the whole fleet in one
process, and time series of its outcomes."""
