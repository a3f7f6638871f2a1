"""Deployment: export a trained model to ONNX (:mod:`opnet.deploy.export`, needs PyTorch) and run
it without PyTorch (:mod:`opnet.deploy.runtime`: numpy, OpenCV, SciPy and onnxruntime)."""
