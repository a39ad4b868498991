"""Radar tracking with neural networks: simulation, training, tracking and evaluation."""

__version__ = "0.1.0"
