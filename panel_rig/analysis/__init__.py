"""Analyses built on the model: flutter, LCO and forced-response sweeps, signal metrics."""
