"""Torch-free runtime: policy backends, safety monitor, fallback controller, MAVLink node."""
