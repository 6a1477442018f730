"""What a policy file is, torch-free: the model contract (`ModelInfo`: layout, task, vehicle, timing,
golden vectors), reading and checking an ONNX file from quad-export (`model.read_model`), the
structural check of its graph (`graph`), and the network it describes (`network`), from which the
runtime's backends and the C generator both work."""
