"""Onboard deployment: ONNX export and onnxruntime scoring."""
