"""Geometry primitives shared by every stage (float64, guarded normalisations, no NaN results)."""
