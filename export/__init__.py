"""ONNX export of the learned matcher (roadmap: next issue)."""
