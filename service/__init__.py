"""Serving side of itnet (onnxruntime + numpy, no torch): runtime, anytime engine, HTTP service."""
