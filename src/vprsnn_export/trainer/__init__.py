"""STDP training of the place-recognition SNN and its calibration (paper Sections III-C to III-E)."""
