"""The stand-in stereo network: architecture, procedural training data, training, weights.

A small network with IGEV's conventions, trained here on procedural pairs; the bundled
ONNX export in ``weights/`` is the default backbone
(:func:`srde_fusion.adapters.load_backbone`). Import the modules directly: ``network``
needs torch, ``training`` imports it when it runs.
"""
