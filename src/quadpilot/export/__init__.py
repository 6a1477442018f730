"""Export (torch + onnx): deployable wrapper, ONNX export with metadata, parity checks."""
