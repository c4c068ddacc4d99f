"""Skyline matching: FFT scores over every heading (with masks and tilt invariance) and the streamed search."""
