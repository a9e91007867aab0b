"""Centralised solvers shared by every method: chordal initialisation and LM."""
