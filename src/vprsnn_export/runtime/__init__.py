"""Inference, neuron assignment, metrics, sequence aggregation, verification and reports."""
