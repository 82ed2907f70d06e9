"""ONNX export of one IT-Net step (torch -> a single-file ONNX graph with a model card)."""
