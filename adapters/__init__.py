"""Backbone adapters: ONNX and torch stereo models behind one callable contract."""
