"""Quantisation of a trained float network into a fixed-point model."""
