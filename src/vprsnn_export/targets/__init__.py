"""Deployment targets: the bit-exact integer simulator, NIR, a Loihi-style description and ONNX."""
