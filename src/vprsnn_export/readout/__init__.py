"""The paper's readout: neuron assignment (Standard, Weighted, W+Prob), exact metrics, sequence aggregation, the SAD baseline."""
