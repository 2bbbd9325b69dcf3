"""Beam-free studies around the engine: comparing methods (comparison), the truth of simulated flights
(truth) and accuracy against it (evaluate). The command line's compare, simulate and evaluate call these."""
