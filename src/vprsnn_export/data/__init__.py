"""The data: manifests and folders of traversals, frames, the synthetic route, preprocessing (CHANNELS) and the Bernoulli spike encoder."""
