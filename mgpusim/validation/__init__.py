"""Measured runs read and checked, compared with the model, and repeated on noisy machines."""
