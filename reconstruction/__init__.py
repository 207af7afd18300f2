"""Calibrated multi-view images to complete, intersection-free 4D garment sequences."""
