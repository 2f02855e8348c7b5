"""Measured runs read and checked, compared with the model (cross-validation and replay)."""
